"""The Ray path of :func:`run_chunks`: chunks as Ray tasks, a bounded number in flight,
collected as they finish, a chunk whose worker or node died submitted again.

Ray is imported here only, so the rest of the package loads without it.
"""
from __future__ import annotations

import logging
import os
import re
import socket
import time
from collections import deque
from typing import Any, Callable

from pytest_driveeval.execute.chunk_results import (ChunkError, ChunkRun, ExecutorError, Placement, Progress, Tally,
                                                    UnreachableCluster, describe_chunk, failure_message)
from pytest_driveeval.execute.spec import ExecutorSpec, host_port

__all__ = ["default_in_flight", "disconnect", "run_on_ray", "run_one"]

# Whether this process called ray.init(); a cluster someone else connected to is theirs to close.
_connected_here = False
_COLOURS = re.compile(r"\x1b\[[0-9;]*m")


def _ray():
    try:
        import ray
    except ImportError:
        raise ExecutorError("Executor Kind: ray needs Ray in this environment: "
                            "pip install 'pytest-driveeval[ray]'") from None
    return ray


#: seconds the reachability probe waits for a TCP connection, and then for the answer to its
#: gRPC greeting: a cluster's port answers in milliseconds even across a data centre; a dead one,
#: or a listener that accepts and never answers, must not cost each item Ray's own timeouts
PROBE_SECONDS = 3.0
# Per process and address, the message of a cluster that could not be reached: every item that
# asks for it again fails at once with the same words instead of waiting for Ray once more.
_unreachable: dict[str | None, str] = {}

# Both a GCS address and a Ray Client (ray://) address are gRPC servers, which speak HTTP/2: to a
# client's connection preface and SETTINGS frame a server answers with its own SETTINGS frame
# (RFC 9113, 3.4).  A port that accepts and stays silent (or speaks something else) would
# otherwise leave ray.init retrying for ever, deaf to SIGTERM.
_HTTP2_PREFACE = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n" + bytes([0, 0, 0, 4, 0, 0, 0, 0, 0])
_SETTINGS_FRAME = 4


def _tls() -> bool:
    # With RAY_USE_TLS the gRPC ports expect a TLS handshake first: the plain greeting cannot tell.
    return os.environ.get("RAY_USE_TLS", "0").lower() in ("1", "true")


def _greeting_unanswered(connection: socket.socket, host: str, port: int) -> str | None:
    """Why the peer at ``host:port`` is no gRPC server (None: it answered as one)."""
    try:
        connection.sendall(_HTTP2_PREFACE)
        reply = b""
        while len(reply) < 9:  # a frame's header: 3 bytes length, 1 type, 1 flags, 4 stream
            chunk = connection.recv(9 - len(reply))
            if not chunk:
                break
            reply += chunk
    except TimeoutError:
        return (f"{host}:{port} accepted the connection but did not answer a gRPC (HTTP/2) greeting within "
                f"{PROBE_SECONDS:g} s: check that the address is the cluster's GCS port ('ray start --head' "
                "prints it) or its Ray Client port (ray://, default 10001)")
    except OSError as exc:
        return f"{host}:{port} accepted the connection, then: {exc.strerror or exc}"
    if len(reply) == 9 and reply[3] == _SETTINGS_FRAME:
        return None
    what = f"answered {reply[:9]!r}" if reply else "closed the connection"
    return (f"{host}:{port} {what} where a gRPC (HTTP/2) server sends its settings: no Ray cluster listens there; "
            "check the port ('ray start --head' prints the GCS address)")


def _probe(address: str) -> str | None:
    """Why nothing answers at ``host:port`` / ``ray://host:port`` as Ray would (None: a gRPC server
    answers).  Ray itself retries a GCS address forever and a Ray Client address for ~30 s, deaf to
    SIGTERM."""
    endpoint = host_port(address)
    if endpoint is None:  # auto, local: Ray finds the cluster itself
        return None
    host, port = endpoint
    try:
        with socket.create_connection((host, port), timeout=PROBE_SECONDS) as connection:
            return None if _tls() else _greeting_unanswered(connection, host, port)
    except ConnectionRefusedError:
        return f"nothing listens on port {port} of {host} (connection refused)"
    except socket.gaierror as exc:
        return f"unknown host {host!r} ({exc.strerror})"
    except TimeoutError:
        return f"no answer from {host}:{port} within {PROBE_SECONDS:g} s"
    except OSError as exc:
        return f"{host}:{port}: {exc.strerror or exc}"


def connect(spec: ExecutorSpec) -> None:
    """Connect to the spec's cluster, or raise :class:`UnreachableCluster`: once per process and
    address, after a fast TCP probe of an explicit host:port."""
    global _connected_here
    ray = _ray()
    if ray.is_initialized():
        return
    where = spec.Address or "Ray's default address (RAY_ADDRESS, or a local cluster)"
    if spec.Address not in _unreachable:
        why = _probe(spec.Address or os.environ.get("RAY_ADDRESS", ""))
        if why is None:
            try:
                ray.init(address=spec.Address, logging_level=logging.WARNING)
            except (ConnectionError, RuntimeError, ValueError) as exc:
                why = str(exc)
            else:
                _connected_here = True
                return
        _unreachable[spec.Address] = (f"cannot reach a Ray cluster at {where}: {why} (checked once per "
                                      "session; every item that needs it fails with this message)")
    raise UnreachableCluster(_unreachable[spec.Address], spec.Address)


def disconnect() -> None:
    """Close the connection this process opened (and the private local cluster ``ray.init``
    started, if it started one); a connection made by someone else is left alone."""
    global _connected_here
    if _connected_here:
        import ray

        if ray.is_initialized():
            ray.shutdown()
        _connected_here = False


def run_one(task_fn: Callable, chunk: Any, *shared: Any) -> tuple[Any, str, str, int, float]:
    """One chunk on a Ray worker: its result and where it ran."""
    import ray

    begun = time.perf_counter()
    result = task_fn(chunk, *shared)
    seconds = time.perf_counter() - begun
    return result, ray.get_runtime_context().get_node_id(), socket.gethostname(), os.getpid(), seconds


def _worker_and_traceback(exc: BaseException) -> tuple[str, str]:
    """Which worker raised, and its traceback, from Ray's text of a task's error: its first
    line names the task and ``(pid=..., ip=...)``, in terminal colours."""
    lines = _COLOURS.sub("", str(exc)).splitlines()
    found = re.search(r"\((pid=\d+, ip=[^)]*)\)", lines[0]) if lines else None
    return (f"a Ray worker ({found.group(1)})" if found else "a Ray worker"), "\n".join(lines[1:])


def _lost_worker_errors(ray) -> tuple[type[BaseException], ...]:
    """Ray's errors for a task whose worker, node or result died under it (some are missing
    from older Ray releases)."""
    names = ("WorkerCrashedError", "NodeDiedError", "LocalRayletDiedError", "ObjectLostError",
             "OutOfMemoryError", "RaySystemError")
    return tuple(getattr(ray.exceptions, name) for name in names if hasattr(ray.exceptions, name))


def _first_line(exc: BaseException) -> str:
    lines = _COLOURS.sub("", str(exc)).strip().splitlines()
    return lines[0] if lines else ""


def default_in_flight(spec: ExecutorSpec) -> int:
    """Twice the tasks the cluster can run at once: each worker has its next chunk waiting
    while the driver collects the last one, and no more, so a failure wastes little."""
    if spec.MaxInFlight:
        return spec.MaxInFlight
    cpus = _ray().cluster_resources().get("CPU", 1.0)
    return max(1, int(2 * cpus / spec.NumCpus))


def run_on_ray(spec: ExecutorSpec, work: list, task_fn: Callable, shared: Any,
               progress: Progress | None) -> ChunkRun:
    ray = _ray()
    from ray.exceptions import RayError, RayTaskError

    connect(spec)
    started = time.perf_counter()
    total = len(work)
    tally = Tally(total)
    in_flight = default_in_flight(spec)
    # Each chunk's attempts are counted here, not by Ray's max_retries: Ray tells neither the
    # task nor its caller how many attempts it took, and the report says which chunks were
    # retried.  A result lost with its node after it finished is resubmitted the same way.
    remote = ray.remote(run_one)
    options = dict(num_cpus=spec.NumCpus, max_retries=0, retry_exceptions=False,
                   **({"runtime_env": spec.RuntimeEnv} if spec.RuntimeEnv else {}))
    # Put once, sent by reference: the function (by name) and the data every chunk reads.
    task_ref = ray.put(task_fn)
    extra = () if shared is None else (ray.put(shared),)

    queue = deque(range(total))
    attempts = [0] * total
    pending: dict[Any, tuple[int, float]] = {}
    failures: dict[int, str] = {}
    causes: dict[int, BaseException] = {}
    lost = _lost_worker_errors(ray)

    def submit(index: int) -> None:
        attempts[index] += 1
        ref = remote.options(name=f"driveeval chunk {index}", **options).remote(task_ref, work[index], *extra)
        pending[ref] = (index, time.perf_counter())

    if progress is not None:
        progress(0, total)
    try:
        while pending or (queue and not failures):
            # After a failure nothing new starts; what is running finishes and is kept.
            while queue and not failures and len(pending) < in_flight:
                submit(queue.popleft())
            [ref], _ = ray.wait(list(pending), num_returns=1)
            index, submitted = pending.pop(ref)
            try:
                result, node_id, host, pid, seconds = ray.get(ref)
            except RayTaskError as exc:
                own = exc.cause if isinstance(getattr(exc, "cause", None), BaseException) else exc
                where, tb = _worker_and_traceback(exc)
                failures[index] = failure_message(index, total, work[index], where, own, tb)
                causes[index] = own
            except lost as exc:
                # The worker, its node or the object holding the result is gone: not the chunk's fault.
                if attempts[index] <= spec.Retries:
                    queue.appendleft(index)
                    continue
                failures[index] = (f"{describe_chunk(index, total, work[index])} failed: its worker died "
                                   f"{attempts[index]} times (Retries: {spec.Retries}); last: "
                                   f"{type(exc).__name__}: {_first_line(exc)}")
            except RayError as exc:
                # Cancelled, unschedulable, a RuntimeEnv that cannot be set up: another attempt
                # would meet the same fate.
                failures[index] = (f"{describe_chunk(index, total, work[index])} could not run: "
                                   f"{type(exc).__name__}: {_first_line(exc)}")
            else:
                wall = time.perf_counter() - submitted
                tally.done(index, result, Placement(index, node_id, host, pid, attempts[index], seconds, wall),
                           progress)
    finally:
        # Interrupted (Ctrl-C, a failure in progress()): leave no task running on the cluster.
        for ref in pending:
            ray.cancel(ref)
    if failures:
        raise ChunkError(total, failures, tally.results, tally.placements, causes.get(min(failures)))
    return tally.finished(spec.describe(), started)
