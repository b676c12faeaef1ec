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
