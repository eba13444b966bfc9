"""A Ray address where no cluster answers fails every item that needs it at once, with one
located message, and the items beside it run.  Port 1 of 127.0.0.1 refuses connections; Ray
alone would retry a GCS address there forever and a ``ray://`` one for ~30 s per item."""
from __future__ import annotations

import json

import pytest

from conftest import NO_HYPOTHESIS_PLUGIN, POLICY_BENCHMARK_HEAD, fresh_pytest_run

pytest.importorskip("ray")
pytest.importorskip("torch")

BENCH = POLICY_BENCHMARK_HEAD + """\
  Blueprint: {{Name: merging}}
  Episodes: 4
  Policies:
    mine: constant
  Judged: [mine]
{executor}"""

REFUSED = "cannot reach a Ray cluster at {address}: nothing listens on port 1 of 127.0.0.1 (connection refused)"


def listening_silently(listener):
    """``listener`` bound and listening: connections are accepted (the kernel's backlog) and never answered."""
    listener.bind(("127.0.0.1", 0))
    listener.listen(8)
    return listener.getsockname()[1]


@pytest.fixture(scope="module")
def module_silent_port():
    import socket

    with socket.socket() as listener:
        yield listening_silently(listener)


@pytest.fixture(scope="module")
def bad_addresses(tmp_path_factory, module_silent_port):
    """One session of four items: one with no executor, and one each whose scenario names a refused GCS
    address, a refused Ray Client address, and an address that accepts and never answers (the
    tests below read it; each such session starts a Python with torch).  In a subprocess with a
    timeout: the guard against the hang these tests are about (ray.init at a silent port waits for
    ever and ignores SIGTERM).  Returns (exit code, output, the items' records by scenario name)."""
    folder = tmp_path_factory.mktemp("bad_addresses")
    texts = {"good": BENCH.format(name="good", executor=""),
             "gcs": BENCH.format(name="gcs", executor='  Executor: {Kind: ray, Address: "127.0.0.1:1"}\n'),
             "client": BENCH.format(name="client", executor="  Executor:\n    Kind: ray\n"
                                                            "    ChunkSize: 2\n"
                                                            "    Address: ray://127.0.0.1:1\n"),
             "silent": BENCH.format(name="silent", executor='  Executor: {Kind: ray, Address: '
                                                            f'"127.0.0.1:{module_silent_port}"}}\n')}
    for name, text in texts.items():
        (folder / f"{name}.scenario.yaml").write_text(text)
    done = fresh_pytest_run(folder, "-q", "-p", "no:randomly", "-p", "no:cacheprovider", *NO_HYPOTHESIS_PLUGIN,
                            timeout=240)
    records = json.loads((folder / "driveeval-results" / "summary.json").read_text())["results"]
    return done.returncode, done.stdout, {r["scenario"]: r for r in records}


def test_a_dead_address_fails_each_item_that_needs_it_with_its_line_and_the_good_one_passes(bad_addresses):
    ret, out, records = bad_addresses
    assert ret == 1 and set(records) == {"good", "gcs", "client", "silent"}
    assert {name: r["status"] for name, r in records.items() if name != "silent"} == {
        "good": "passed", "gcs": "failed", "client": "failed"}
    pytest.LineMatcher(out.splitlines()).fnmatch_lines([
        "*UnreachableCluster: client.scenario.yaml:14: Evaluation.Executor.Address: "
        + REFUSED.format(address="ray://127.0.0.1:1") + " (checked once per session*",
        "*UnreachableCluster: gcs.scenario.yaml:11: Evaluation.Executor.Address: "
        + REFUSED.format(address="127.0.0.1:1") + "*",
    ])
    assert "Traceback" not in out


def test_the_session_option_address_is_probed_once_and_named_for_every_item(pytester):
    for name in ("a", "b", "c"):
        pytester.makefile(".scenario.yaml", **{name: BENCH.format(name=name, executor="")})
    result = pytester.runpytest_subprocess("-q", "-p", "no:randomly", *NO_HYPOTHESIS_PLUGIN, "-n", "2",
                                           "--driveeval-executor", "{Kind: ray, Address: 127.0.0.1:1}", timeout=240)
    result.assert_outcomes(failed=3)
    message = ("UnreachableCluster: --driveeval-executor / driveeval_executor: Address: "
               + REFUSED.format(address="127.0.0.1:1"))
    # Read per item from the summary: the terminal repeats it (the table, and pytest's short summary
    # in full where CI is set), so counting it there depends on the terminal.
    records = json.loads((pytester.path / "driveeval-results" / "summary.json").read_text())["results"]
    assert len(records) == 3 and all(message in record["message"] for record in records)
    assert message in result.stdout.str()


def test_an_unreachable_address_is_probed_once_per_process(monkeypatch):
    from pytest_driveeval.execute import ExecutorSpec, UnreachableCluster, ray_path

    probes = []
    monkeypatch.setattr(ray_path, "_unreachable", {})
    monkeypatch.setattr(ray_path, "_probe", lambda address: probes.append(address) or "closed")
    spec = ExecutorSpec(Kind="ray", Address="ray://127.0.0.1:1")
    messages = []
    for _ in range(3):
        with pytest.raises(UnreachableCluster) as raised:
            ray_path.connect(spec)
        messages.append(str(raised.value))
    assert probes == ["ray://127.0.0.1:1"]
    assert messages == [messages[0]] * 3 and "closed" in messages[0]


@pytest.mark.parametrize("address, host_port", [("127.0.0.1:1", True), ("ray://localhost:1", True),
                                                ("[::1]:1", True), ("auto", False), ("local", False)])
def test_only_an_explicit_host_and_port_is_probed(address, host_port):
    from pytest_driveeval.execute import ray_path

    why = ray_path._probe(address)
    assert (why is not None) == host_port


@pytest.fixture
def silent_port():
    """A port that accepts connections (the kernel's backlog) and never answers."""
    import socket

    with socket.socket() as listener:
        yield listening_silently(listener)


def test_a_listener_that_never_answers_fails_the_probe_within_its_time(silent_port, monkeypatch):
    from pytest_driveeval.execute import ray_path

    monkeypatch.setattr(ray_path, "PROBE_SECONDS", 0.2)
    monkeypatch.delenv("RAY_USE_TLS", raising=False)
    for address in (f"127.0.0.1:{silent_port}", f"ray://127.0.0.1:{silent_port}"):
        assert ray_path._probe(address) == (
            f"127.0.0.1:{silent_port} accepted the connection but did not answer a gRPC (HTTP/2) greeting within "
            "0.2 s: check that the address is the cluster's GCS port ('ray start --head' prints it) or its Ray "
            "Client port (ray://, default 10001)")


def serve_once(reply: bytes):
    """A port whose first connection gets ``reply`` to whatever it sends, then is closed."""
    import socket
    import threading

    listener = socket.socket()
    listener.bind(("127.0.0.1", 0))
    listener.listen(1)

    def answer():
        connection, _ = listener.accept()
        with connection, listener:
            connection.recv(64)
            connection.sendall(reply)

    threading.Thread(target=answer, daemon=True).start()
    return listener.getsockname()[1]


def test_a_grpc_server_passes_the_probe_and_another_server_does_not(monkeypatch):
    from pytest_driveeval.execute import ray_path

    monkeypatch.delenv("RAY_USE_TLS", raising=False)
    settings = bytes([0, 0, 6, 4, 0, 0, 0, 0, 0, 0, 3, 0, 0, 0, 100])  # an HTTP/2 SETTINGS frame, as gRPC sends
    assert ray_path._probe(f"127.0.0.1:{serve_once(settings)}") is None
    port = serve_once(b"HTTP/1.1 400 Bad Request\r\n\r\n")
    assert ray_path._probe(f"127.0.0.1:{port}") == (
        f"127.0.0.1:{port} answered b'HTTP/1.1 ' where a gRPC (HTTP/2) server sends its settings: no Ray cluster "
        "listens there; check the port ('ray start --head' prints the GCS address)")


def test_an_item_whose_address_never_answers_fails_at_its_line_and_the_good_one_passes(bad_addresses,
                                                                                         module_silent_port):
    ret, out, records = bad_addresses
    silent_port = module_silent_port
    assert ret == 1 and set(records) == {"good", "gcs", "client", "silent"}
    assert {name: r["status"] for name, r in records.items() if name in ("good", "silent")} == {
        "good": "passed", "silent": "failed"}
    pytest.LineMatcher(out.splitlines()).fnmatch_lines([
        f"*UnreachableCluster: silent.scenario.yaml:11: Evaluation.Executor.Address: cannot reach a Ray cluster at "
        f"127.0.0.1:{silent_port}: 127.0.0.1:{silent_port} accepted the connection but did not answer a gRPC (HTTP/2) "
        "greeting within 3 s*"])
    assert "Traceback" not in out
