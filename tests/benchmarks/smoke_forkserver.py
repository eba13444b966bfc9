"""A process that imports the benchmarks' heavy libraries once and runs each smoke script in a fork of
itself: the script still runs start to end as ``python SCRIPT --smoke`` in a process of its own (its own
globals, argv, working folder, stdout and stderr, exit status), without paying the interpreter's start
and torch's import (~3 s) again for each of twenty scripts.

Protocol, one JSON line each way per script: ``{"script", "out", "err", "cwd", "timeout"}`` in,
``{"returncode"}`` out (negative: killed by that signal, as subprocess reports it).
"""
from __future__ import annotations

import atexit
import importlib
import json
import os
import runpy
import signal
import sys
import traceback
import warnings

# Imported before any fork; nothing here starts a thread (torch's pools start on first use).
PRELOAD = ("numpy", "torch", "numba", "scipy", "pytest_driveeval", "pytest_driveeval.policies.loading",
           "pytest_driveeval.sim.episodes", "pytest_driveeval.io.l5.l5kit_zarr")


def run_child(script: str, out: str, err: str, cwd: str, timeout: int) -> None:
    """In the fork: become ``python script --smoke`` and never return."""
    code = 1
    try:
        signal.alarm(timeout)  # default action kills the child, as subprocess's timeout would
        os.chdir(cwd)
        written = os.O_WRONLY | os.O_CREAT | os.O_TRUNC
        for fd, path, mode in ((0, os.devnull, os.O_RDONLY), (1, out, written), (2, err, written)):
            target = os.open(path, mode)
            os.dup2(target, fd)
            os.close(target)
        sys.argv = [script, "--smoke"]
        sys.path[0] = os.path.dirname(script)  # as the interpreter sets it for a script
        runpy.run_path(script, run_name="__main__")
        code = 0
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
        if not isinstance(exc.code, (int, type(None))):
            print(exc.code, file=sys.stderr)
    except BaseException:  # noqa: BLE001 - the script's own failure, reported as the interpreter would
        traceback.print_exc()
        code = 1
    finally:
        try:
            with warnings.catch_warnings():
                # At an interpreter's exit these run from C, where a DeprecationWarning is not shown;
                # called from this __main__ module it would be.
                warnings.simplefilter("ignore", DeprecationWarning)
                atexit._run_exitfuncs()
            sys.stdout.flush()
            sys.stderr.flush()
        finally:
            os._exit(code)


def serve() -> None:
    for name in PRELOAD:
        try:
            importlib.import_module(name)
        except ImportError:  # a script that needs it skips, or fails on its own import
            pass
    print(json.dumps({"ready": True}), flush=True)
    for line in sys.stdin:
        ask = json.loads(line)
        sys.stdout.flush()
        sys.stderr.flush()
        pid = os.fork()
        if pid == 0:
            run_child(ask["script"], ask["out"], ask["err"], ask["cwd"], ask["timeout"])
        _, status = os.waitpid(pid, 0)
        print(json.dumps({"returncode": os.waitstatus_to_exitcode(status)}), flush=True)


if __name__ == "__main__":
    serve()
