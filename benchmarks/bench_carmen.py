"""CARMEN parsing speed: probmap's reader beside its floor and a naive parser, in one run.

Rows, all on the same file in the same process (best of ``--repeat`` runs each):

- ``decompress + split lines``: the floor, no number parsed;
- ``naive float() parser``: the obvious loop, ``[float(x) for x in fields]`` per FLASER line,
  no validation, no ODOM;
- ``probmap load_scans``: every FLASER and ODOM line parsed and validated, arrays stacked;
- ``probmap CarmenLog iteration``: streaming LaserScan records.

Then the map of that log (odometry poses, 0.05 m) is written by ``save_map`` (YAML + PGM + NPZ +
PNG through temporary files, fsync and renames) beside a reference that only encodes the same
files in memory with numpy's ``savez_compressed`` and pillow's default PNG settings.

Run:  python benchmarks/bench_carmen.py [--log PATH] [--repeat 3]
"""

from __future__ import annotations

import argparse
import time
import tracemalloc
from collections.abc import Callable
from pathlib import Path

import numpy as np

from probmap.datasets.carmen import CarmenLog, load_scans, open_log

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"


def floor(path: Path) -> int:
    n = 0
    with open_log(path) as f:
        for line in f:
            n += len(line.split()) > 0
    return n


def naive(path: Path) -> int:
    rows = []
    with open_log(path) as f:
        for line in f:
            s = line.split()
            if s and s[0] == "FLASER":
                n = int(s[1])
                rows.append([float(x) for x in s[2 : 2 + n]])
    return len(np.array(rows))


def probmap_batch(path: Path) -> int:
    return len(load_scans(path))


def probmap_stream(path: Path) -> int:
    return sum(1 for _ in CarmenLog(path))


def best_of(fn: Callable[[Path], int], path: Path, repeat: int) -> tuple[float, int]:
    times, n = [], 0
    for _ in range(repeat):
        t0 = time.perf_counter()
        n = fn(path)
        times.append(time.perf_counter() - t0)
    return min(times), n


def peak_mib(fn: Callable[[Path], int], path: Path) -> float:
    tracemalloc.start()
    try:
        fn(path)
        return tracemalloc.get_traced_memory()[1] / 2**20
    finally:
        tracemalloc.stop()


def bench_write(path: Path, repeat: int) -> None:
    import io
    import tempfile

    from PIL import Image

    from probmap.grid import io as gio
    from probmap.pipelines import MappingConfig, map_log

    grid = map_log(path, MappingConfig(resolution=0.05, poses="odometry")).grid  # as `probmap map`

    def reference(_: Path) -> int:
        grey, _alpha = gio.encode_map_server(grid)
        gio.pgm_bytes(grey)
        np.savez_compressed(io.BytesIO(), **gio._npz_arrays(grid))  # type: ignore[arg-type]
        Image.fromarray(gio.preview_image(grid)).save(io.BytesIO(), format="PNG")
        return 4

    with tempfile.TemporaryDirectory() as tmp:
        ours = best_of(lambda _: len(gio.save_map(Path(tmp) / "m", grid)), path, repeat)[0]
    ref = best_of(reference, path, repeat)[0]
    h, w = grid.spec.shape
    print(f"\nWriting the {w} x {h}-cell map (best of {repeat}):\n")
    print("| writer | seconds | vs reference |\n| --- | ---: | ---: |")
    print(f"| probmap save_map (4 files, atomic) | {ours:.3f} | {ref / ours:.2f}x |")
    print(f"| reference: numpy/pillow defaults, in memory | {ref:.3f} | 1.00x |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--log", type=Path, default=DATA / "intel-research-lab" / "intel.clf.bz2")
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    rows = [
        ("decompress + split lines", floor),
        ("naive float() parser (FLASER only)", naive),
        ("probmap load_scans (all lines, validated)", probmap_batch),
        ("probmap CarmenLog iteration", probmap_stream),
    ]
    print(f"log: {args.log} ({args.log.stat().st_size / 2**20:.1f} MiB on disk)\n")
    results = [(name, *best_of(fn, args.log, args.repeat)) for name, fn in rows]
    base = results[1][1]
    print("| step | seconds | items | vs naive parser |\n| --- | ---: | ---: | ---: |")
    for name, sec, n in results:
        print(f"| {name} | {sec:.3f} | {n:,} | {base / sec:.2f}x |")
    stream = peak_mib(probmap_stream, args.log)
    batch = peak_mib(probmap_batch, args.log)
    print(
        f"\nPeak traced Python memory: streaming iteration {stream:.1f} MiB, "
        f"load_scans {batch:.1f} MiB (the stacked float64 arrays are part of it)"
    )
    bench_write(args.log, args.repeat)


if __name__ == "__main__":
    main()
