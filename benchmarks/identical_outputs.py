"""Fingerprints of what probmap writes, for checking that a refactoring changes no result.

Runs the command line on the shared data (laser SLAM with both methods on four logs, the four
landmark SLAM methods on MRCLAM robots 1-3 and Victoria Park, ``optimize`` on every pose graph)
and prints one sha256 per result file: map rasters, trajectories, g2o files and landmark
estimates. ``.npz`` files are hashed array by array (their zip headers carry the write time);
configuration records and pictures are left out (they name versions and fonts, not results).

Run it on two revisions and compare the JSON files::

    PYTHONPATH=/path/to/old/src python benchmarks/identical_outputs.py -o old.json
    python benchmarks/identical_outputs.py -o new.json
    python benchmarks/identical_outputs.py --compare old.json new.json
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import tempfile
import time
import zipfile
from pathlib import Path

import numpy as np

DATA = Path(os.environ.get("PROBMAP_DATA", Path(__file__).resolve().parents[2] / "shared/data"))

LASER = {
    "intel": "intel",
    "hospital": "freiburg-clinic",
    "intel-bag": "intel-bag",
    "fr079": str(DATA / "freiburg-079/fr079.clf.bz2"),
}
LANDMARK_METHODS = ("ekf", "seif", "fastslam", "graphslam")
RUN_FIELDS = {"command", "probmap_version", "peak_rss_mb", "step_ms", "time_s"}
RESULT_SUFFIXES = (".pgm", ".npz", ".csv", ".g2o", ".tum", ".json")


def _hash_file(path: Path) -> str:
    if path.suffix == ".npz":
        digest = hashlib.sha256()
        with np.load(path, allow_pickle=False) as data, zipfile.ZipFile(path):
            for name in sorted(data.files):
                arr = data[name]
                digest.update(name.encode() + str(arr.dtype).encode() + str(arr.shape).encode())
                digest.update(np.ascontiguousarray(arr).tobytes())
        return digest.hexdigest()
    if path.suffix == ".json":
        # metrics.json also records the command line, the version, run times and memory
        record = json.loads(path.read_text())
        record = {k: v for k, v in record.items() if k not in RUN_FIELDS}
        return hashlib.sha256(json.dumps(record, sort_keys=True).encode()).hexdigest()
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _run(args: list[str], log: list[str]) -> float:
    start = time.perf_counter()
    proc = subprocess.run(["probmap", *args], capture_output=True, text=True)
    seconds = time.perf_counter() - start
    if proc.returncode != 0:
        log.append(f"FAILED ({proc.returncode}): probmap {' '.join(args)}\n{proc.stderr[-2000:]}")
    return seconds


def jobs(quick: bool) -> list[tuple[str, list[str]]]:
    """``(name, probmap arguments with {out} for the output)``."""
    out: list[tuple[str, list[str]]] = []
    end = ["--end-time", "300"] if quick else []
    for name, src in LASER.items():
        for method in ("graph", "rbpf"):
            out.append(
                (
                    f"laser/{name}/{method}",
                    ["slam", "grid", src, "-o", "{out}/slam", "--method", method, *end],
                )
            )
    for robot in (1, 2, 3):
        for method in LANDMARK_METHODS:
            out.append(
                (
                    f"landmark/mrclam{robot}/{method}",
                    [
                        "slam",
                        method,
                        "mrclam7",
                        "--robot",
                        str(robot),
                        "-o",
                        "{out}",
                        "--no-plot",
                        *end,
                    ],
                )
            )
    for method in LANDMARK_METHODS:
        out.append(
            (
                f"landmark/victoria-park/{method}",
                ["slam", method, "victoria-park", "-o", "{out}", "--no-plot", *end],
            )
        )
    for graph in sorted((DATA / "pose-graphs").iterdir()):
        out.append((f"posegraph/{graph.name}", ["optimize", str(graph), "-o", "{out}/out.g2o"]))
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-o", "--output", type=Path, help="JSON file of the fingerprints")
    parser.add_argument("--quick", action="store_true", help="first 300 s of every log only")
    parser.add_argument("--only", default="", help="run only jobs whose name contains this")
    parser.add_argument("--compare", nargs=2, type=Path, metavar=("OLD", "NEW"))
    args = parser.parse_args()
    if args.compare:
        old, new = (json.loads(p.read_text()) for p in args.compare)
        keys = sorted(set(old) | set(new))
        bad = [k for k in keys if old.get(k) != new.get(k)]
        for k in bad:
            print(f"DIFFERS {k}: {old.get(k)} != {new.get(k)}")
        print(f"{len(keys) - len(bad)} of {len(keys)} fingerprints identical")
        return 1 if bad else 0
    prints: dict[str, str] = {}
    failures: list[str] = []
    for name, argv in jobs(args.quick):
        if args.only and args.only not in name:
            continue
        with tempfile.TemporaryDirectory() as tmp:
            seconds = _run([a.replace("{out}", tmp) for a in argv], failures)
            files = sorted(p for p in Path(tmp).rglob("*") if p.suffix in RESULT_SUFFIXES)
            for path in files:
                prints[f"{name}/{path.relative_to(tmp)}"] = _hash_file(path)
        print(f"{name:40s} {len(files):2d} files {seconds:7.1f} s", flush=True)
    if args.output:
        args.output.write_text(json.dumps(prints, indent=1, sort_keys=True) + "\n")
    for failure in failures:
        print(failure, file=sys.stderr)
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
