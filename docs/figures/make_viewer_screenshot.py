"""Screenshot of a run.rrd as the viewer opens it, with rerun's headless viewer (no display needed).

    .venv/bin/python docs/figures/make_viewer_screenshot.py out/demo/run.rrd docs/figures/viewer_calibration.png

Needs a Vulkan driver, a software one will do (Debian: apt-get install mesa-vulkan-drivers).
The viewer is given `--wait` seconds to load the file before the shot; the shot is then scaled to
`--width` pixels and reduced to 256 colours (a small file for the docs). The software renderer is
slow: a file of a few hundred thousand points per cloud (--viewer-points) is what it draws in time.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

from PIL import Image
from rerun.experimental import ViewerClient

from graphcal.viewer.stream import viewer_executable


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("rrd", type=Path)
    parser.add_argument("png", type=Path)
    parser.add_argument("--wait", type=float, default=20.0, help="seconds to let the viewer load the file")
    parser.add_argument("--port", type=int, default=9877)
    parser.add_argument("--width", type=int, default=1440, help="width of the PNG [pixels]")
    args = parser.parse_args()
    os.environ.setdefault("XDG_RUNTIME_DIR", "/tmp")  # the viewer wants one, even headless
    client = ViewerClient.spawn(headless=True, port=args.port, executable_path=viewer_executable(),
                                hide_welcome_screen=True)
    try:
        client.open(str(args.rrd.resolve()))
        time.sleep(args.wait)
        client.save_screenshot(str(args.png))
    finally:
        client.quit()
    image = Image.open(args.png).convert("RGB")
    image = image.resize((args.width, round(image.height * args.width / image.width)), Image.LANCZOS)
    image.quantize(colors=256, method=Image.Quantize.FASTOCTREE, dither=Image.Dither.NONE).save(args.png, optimize=True)
    print(f"wrote {args.png}")


if __name__ == "__main__":
    main()
