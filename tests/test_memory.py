"""``release_freed_memory``: glibc's malloc_trim on Linux, a no-op elsewhere."""

import sys

from probmap._memory import release_freed_memory


def test_release_freed_memory_runs_where_glibc_is():
    done = release_freed_memory()
    assert isinstance(done, bool)
    if sys.platform.startswith("linux"):
        import platform

        if platform.libc_ver()[0] == "glibc":
            assert done
    else:
        assert not done


_FREED_SCRIPT = """
import sys
import numpy as np
from probmap._memory import map_large_blocks

def rss():
    with open("/proc/self/status") as f:
        return next(int(line.split()[1]) for line in f if line.startswith("VmRSS")) / 1024

if sys.argv[1] == "mapped":
    assert map_large_blocks()
big = np.ones(24 << 17)  # 24 MiB, freed: glibc's threshold for a block of its own rises
del big
small = [np.ones(6 << 17) for _ in range(4)]  # 4 blocks of 6 MiB, written, then freed
start = rss()
del small
print(start - rss())
"""


def _freed_mib(mode: str) -> float:
    import subprocess

    out = subprocess.run(
        [sys.executable, "-c", _FREED_SCRIPT, mode], capture_output=True, text=True, check=True
    )
    return float(out.stdout)


def test_map_large_blocks_gives_freed_blocks_back():
    """Blocks of 6 MiB freed after a larger one: glibc keeps them resident in its heap (the
    oracle that the test can fail), and gives them back once ``map_large_blocks`` ran. In a
    process of its own: the setting lasts for the rest of the process."""
    import platform

    import pytest

    if not sys.platform.startswith("linux") or platform.libc_ver()[0] != "glibc":
        from probmap._memory import map_large_blocks

        assert not map_large_blocks()
        pytest.skip("glibc only")
    assert _freed_mib("mapped") > 20.0
    assert _freed_mib("default") < 4.0
