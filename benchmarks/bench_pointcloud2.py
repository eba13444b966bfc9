"""Throughput and peak memory of streaming PointCloud2 out of a ROS 2 bag.

Writes a bag of Autoware PointXYZIRC clouds (16 bytes/point) to a temp dir,
then reads it back in separate child processes (so each peak RSS is its own):

* ``stream``: ``pytest_driveeval.io.ros.rosbag.iter_pointclouds`` (zero-copy views,
  one message alive at a time);
* ``naive``: the usual recipe, rosbags deserialize + ``np.frombuffer(...).copy()``
  of every message into a list;
* ``page cache``: the machine's limit for streaming that bag, its storage
  files read with ``readinto`` in 8 MiB blocks into one preallocated buffer,
  measured right before and right after each stream (the faster of the two
  is that round's reference; ``--repeat`` rounds, the median ratio is the
  headline).

Both readers reduce each cloud (sum of x) so the payload is really touched.
The bag is read right after being written, so it is usually in the page
cache: the figures measure decoding, not the disk.  Each round also counts the
read system calls (Linux): SQLite reads a message's 4 KiB overflow pages one
``pread`` each, about 250,000 calls per GB against the reference's 120, and
that is what bounds the stream.  The stream's figure
counts the points' bytes only, the reference every byte of the files.  The
ratio is also given in CPU time, which a machine shared with other jobs
disturbs less than the wall clock.

    python benchmarks/bench_pointcloud2.py --size-mb 1000 --storage sqlite3 [--repeat 3] [--smoke]
"""
from __future__ import annotations

import argparse
import json
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

SMOKE_HELP = "every part at tiny sizes in seconds, reference venvs skipped: checks the script runs, measures nothing"


def write_bag(path: Path, size_mb: float, points: int, storage: str) -> tuple[int, int]:
    from pytest_driveeval.io.ros.pointcloud2 import XYZIRC_FIELDS, encode_pointcloud2, make_cloud
    from pytest_driveeval.io.ros.rosbag import BagWriter

    cloud = make_cloud(points, XYZIRC_FIELDS)
    per_msg = cloud.nbytes
    count = max(1, int(size_mb * 1e6 // per_msg))
    with BagWriter(path, storage) as w:
        for i in range(count):
            cloud["x"][0] = i  # make messages differ
            stamp = 1_700_000_000_000_000_000 + i * 100_000_000
            w.write("/points", encode_pointcloud2(cloud, "lidar", stamp))
    return count, per_msg


def _read_syscalls() -> int:
    """read-like system calls of this process so far (Linux's /proc/self/io), -1 elsewhere."""
    try:
        with open("/proc/self/io") as f:
            return next(int(line.split()[1]) for line in f if line.startswith("syscr:"))
    except (OSError, StopIteration):
        return -1


def _result(t: float, cpu: float, nbytes: int, frames: int, check: float, syscalls: int) -> dict:
    after = _read_syscalls()
    return {"seconds": time.perf_counter() - t, "cpu_seconds": time.process_time() - cpu,
            "payload_bytes": nbytes, "frames": frames, "check": check,
            "read_syscalls": after - syscalls if syscalls >= 0 else -1}


def run_stream(path: str) -> dict:
    import rosbags.rosbag2  # noqa: F401  (imported outside the timing, as for the naive reader)

    from pytest_driveeval.io.ros.rosbag import default_typestore, iter_pointclouds

    default_typestore()  # one-off setup, built outside the timing as for the naive reader
    calls = _read_syscalls()
    t, cpu = time.perf_counter(), time.process_time()
    nbytes = frames = 0
    acc = 0.0
    for _, _, pts in iter_pointclouds(path, "/points"):
        acc += float(pts["x"].sum())
        nbytes += pts.nbytes
        frames += 1
    return _result(t, cpu, nbytes, frames, acc, calls)


def run_naive(path: str) -> dict:
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    calls = _read_syscalls()
    t, cpu = time.perf_counter(), time.process_time()
    clouds = []
    with Reader(path) as reader:
        conns = [c for c in reader.connections if c.topic == "/points"]
        for conn, _, raw in reader.messages(conns):
            msg = ts.deserialize_cdr(raw, conn.msgtype)
            dtype = np.dtype({"names": [f.name for f in msg.fields],
                              "formats": ["<f4", "<f4", "<f4", "u1", "u1", "<u2"],
                              "offsets": [f.offset for f in msg.fields],
                              "itemsize": msg.point_step})
            clouds.append(np.frombuffer(msg.data, dtype=dtype).copy())
    acc = sum(float(c["x"].sum()) for c in clouds)
    nbytes = sum(c.nbytes for c in clouds)
    return _result(t, cpu, nbytes, len(clouds), acc, calls)


def run_page_cache(path: str, block: int = 8 << 20) -> dict:
    files = sorted(p for p in Path(path).iterdir() if p.suffix in (".db3", ".mcap"))
    buf = memoryview(np.empty(block, dtype=np.uint8))
    calls = _read_syscalls()
    t, cpu = time.perf_counter(), time.process_time()
    nbytes = 0
    for file in files:
        with open(file, "rb", buffering=0) as f:
            while n := f.readinto(buf):
                nbytes += n
    return _result(t, cpu, nbytes, 0, 0.0, calls)


MODES = {"stream": run_stream, "naive": run_naive, "cache": run_page_cache}


def child(mode: str, path: str) -> None:
    out = MODES[mode](path)
    out["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # KiB on Linux
    print(json.dumps(out))


def _gbps(r: dict, key: str = "seconds") -> float:
    return r["payload_bytes"] / r[key] / 1e9


def _per_page(r: dict) -> str:
    # SQLite reads a blob's overflow pages one pread each: what bounds the stream (issue 25's note).
    if r["read_syscalls"] < 0:
        return "n/a"
    return f"{r['read_syscalls']} ({r['read_syscalls'] / (r['payload_bytes'] / 4096):.3f} per 4 KiB)"


def measure(mode: str, path: Path) -> dict:
    res = subprocess.run([sys.executable, __file__, "--child", mode, str(path)],
                         capture_output=True, text=True, check=True)
    return json.loads(res.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--size-mb", type=float, nargs="+", default=[100, 400],
                    help="payload size(s) of the generated bag(s), MB")
    ap.add_argument("--points", type=int, default=200_000, help="points per message")
    ap.add_argument("--storage", choices=["sqlite3", "mcap"], default="sqlite3")
    ap.add_argument("--no-naive", action="store_true", help="skip the reference (it holds the whole bag in RAM)")
    ap.add_argument("--repeat", type=int, default=3, help="rounds of page cache, stream, page cache")
    ap.add_argument("--child", nargs=2, metavar=("MODE", "PATH"), help=argparse.SUPPRESS)
    ap.add_argument("--smoke", action="store_true", help=SMOKE_HELP)
    args = ap.parse_args()
    if args.child:
        child(*args.child)
        return
    if args.smoke:
        args.size_mb, args.points, args.repeat = [1.0], 10_000, 1
        print("smoke run: tiny sizes; the figures mean nothing")
    with tempfile.TemporaryDirectory() as tmp:
        for size in args.size_mb:
            path = Path(tmp) / f"bag_{int(size)}"
            t = time.perf_counter()
            count, per_msg = write_bag(path, size, args.points, args.storage)
            wrote = time.perf_counter() - t
            disk = sum(f.stat().st_size for f in path.iterdir()) / 1e6
            print(f"\n{args.storage} bag: {count} msgs x {per_msg / 1e6:.1f} MB = {count * per_msg / 1e9:.2f} GB "
                  f"payload, {disk:.0f} MB on disk, written in {wrote:.1f} s")
            rounds = []  # the stream between two reads of the page cache, each round in a row
            for _ in range(args.repeat):
                rounds.append([measure("cache", path), measure("stream", path), measure("cache", path)])
            for i, (before, stream, after) in enumerate(rounds, 1):
                ratio, cpu = (_gbps(stream, key) / max(_gbps(before, key), _gbps(after, key))
                              for key in ("seconds", "cpu_seconds"))
                print(f"  round {i}: stream {stream['frames']} frames, {_gbps(stream):.2f} GB/s, peak RSS "
                      f"{stream['peak_rss_mb']:.1f} MB; page cache {_gbps(before):.2f} GB/s before, "
                      f"{_gbps(after):.2f} after: {ratio:.2f} of the faster (in CPU time {cpu:.2f}); "
                      f"read syscalls: stream {_per_page(stream)}, page cache {_per_page(before)}")
                stream.update(ratio=ratio, cpu_ratio=cpu)
            streams = [r[1] for r in rounds]
            print(f"  stream / page cache: median {statistics.median(s['ratio'] for s in streams):.2f} of the "
                  f"faster reference over {len(rounds)} round(s) (target >= 0.50); in CPU time "
                  f"{statistics.median(s['cpu_ratio'] for s in streams):.2f}; peak RSS "
                  f"{max(s['peak_rss_mb'] for s in streams):.1f} MB (target < 100)")
            if not args.no_naive:
                n = measure("naive", path)
                assert all(s["check"] == n["check"] for s in streams), "readers disagree"
                seconds = statistics.median(s["seconds"] for s in streams)
                rss = max(s["peak_rss_mb"] for s in streams)
                print(f"  naive : {n['frames']:5d} frames, {_gbps(n):6.2f} GB/s, peak RSS {n['peak_rss_mb']:7.1f} MB")
                print(f"  stream vs naive: {n['seconds'] / seconds:.2f}x faster, "
                      f"{n['peak_rss_mb'] / rss:.1f}x less peak memory")
            shutil.rmtree(path, ignore_errors=True)  # free disk before the next size


if __name__ == "__main__":
    main()
