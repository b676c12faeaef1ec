"""Render one frame of a live-view recording (``--viz-save FILE.rrd``) to a PNG, headless.

    python docs/live_frame.py RUN.rrd OUT.png SCAN

It starts a headless rerun viewer, opens the recording, moves the ``scan`` timeline to
``SCAN`` and saves a screenshot of the whole viewer (1920 x 1080), reduced to a palette of
128 colours so that it stays small for the README. rerun needs a Vulkan adapter and ``rerun``
on the PATH (``.venv/bin``). On a machine without a GPU, Mesa's software rasteriser lavapipe
works without installing anything system-wide: ``apt-get download mesa-vulkan-drivers
libvulkan1``, unpack both with ``dpkg -x DEB ROOT``, copy
``ROOT/usr/share/vulkan/icd.d/lvp_icd.x86_64.json`` with its ``library_path`` made absolute
(``ROOT/usr/lib/x86_64-linux-gnu/libvulkan_lvp.so``), and run with ``VK_ICD_FILENAMES`` set to
that copy and ``LD_LIBRARY_PATH=ROOT/usr/lib/x86_64-linux-gnu``.
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path


def main(rrd: str, out: str, scan: str, port: int = 9891) -> None:
    from PIL import Image
    from rerun.experimental import ViewerClient

    viewer = ViewerClient.spawn(headless=True, port=port, hide_welcome_screen=True)
    try:
        viewer.open(str(Path(rrd).resolve()), navigate=True)
        time.sleep(8.0)  # the start-up notices fade out
        viewer.set_time(timeline="scan", sequence=int(scan), play_state="paused")
        time.sleep(2.0)
        with tempfile.TemporaryDirectory() as tmp:
            shot = Path(tmp) / "frame.png"
            viewer.save_screenshot(str(shot))
            Image.open(shot).convert("RGB").quantize(128).save(out, optimize=True)
    finally:
        viewer.quit()


if __name__ == "__main__":
    main(*sys.argv[1:4])
