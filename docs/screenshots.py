"""The README's screenshots of ``motionweb app``, taken with headless Chromium (selenium, Debian's
``chromium`` + ``chromium-driver``) on a demo store built here: the search panel with an uploaded
query (KG04 §3.3), a retime session (MPS06) of that upload and a guided-warp session (HDP07) of a demo run.

    .venv/bin/python -m docs.screenshots [--work DIR] [--out docs/img]

Writes ``search-upload.png``, ``retime.png`` and ``warp.png`` (palette PNGs, each under 200 KB).
Builds and indexes a six-clip demo store first (about a minute); not run by the tests.
"""

from __future__ import annotations

import argparse
import io
import os
import shutil
import tempfile
import threading
import time
from pathlib import Path

import yaml

MAX_BYTES = 200_000
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
         "--disable-component-update", "--disable-sync", "--no-first-run", "--window-size=1700,1250",
         "--hide-scrollbars", "--force-device-scale-factor=1"]


def demo_store(work: Path) -> Path:
    """An indexed store of six demo clips (walk, run; 30 fps), its config's path."""
    from motionweb.flows.config import load_config
    from motionweb.flows.index import index_library
    from motionweb.store.demo.corpus import write_demo_corpus
    from motionweb.store.generations import load_generation
    from motionweb.store.zarr_store import MotionStore

    cfg_path = work / "config.yaml"
    cfg_path.write_text(yaml.safe_dump({"corpus": {"path": "corpus", "length_unit": "m"},
                                        "features": {"rates": [10.0, 30.0]}, "store": {"path": "store"},
                                        "dask": {"processes": False}, "output": "out"}))
    if load_generation(MotionStore(str(work / "store"))) is None:
        write_demo_corpus(work / "corpus", seed=7, variants_per_category=3, fps=30.0)
        for d in (work / "corpus").iterdir():
            if d.name not in ("walk", "run"):
                shutil.rmtree(d)
        from prefect.settings import PREFECT_FLOWS_HEARTBEAT_FREQUENCY, temporary_settings

        with temporary_settings({PREFECT_FLOWS_HEARTBEAT_FREQUENCY: None}):
            index_library(load_config(cfg_path))
    return cfg_path


def save(png: bytes, box: tuple[int, int, int, int] | None, out: Path) -> None:
    """``png`` cropped to ``box`` (left, top, right, bottom), as a palette PNG under
    :data:`MAX_BYTES` (scaled down until it fits)."""
    from PIL import Image

    img = Image.open(io.BytesIO(png)).convert("RGB")
    if box is not None:
        img = img.crop((box[0], box[1], min(box[2], img.width), min(box[3], img.height)))
    scale = 1.0
    while True:
        w, h = round(img.width * scale), round(img.height * scale)
        small = img.resize((w, h), Image.LANCZOS) if scale < 1 else img
        buf = io.BytesIO()
        small.quantize(colors=128, method=Image.Quantize.MEDIANCUT).save(buf, "PNG", optimize=True)
        if buf.tell() < MAX_BYTES or scale < 0.3:
            break
        scale *= 0.85
    out.write_bytes(buf.getvalue())
    print(f"{out}: {w}x{h}, {buf.tell() / 1000:.0f} kB")


def union(drv, *ids: str) -> tuple[int, int, int, int]:
    """The page box (pixels) around the elements ``ids``."""
    rects = [drv.execute_script(f"const r = document.getElementById('{i}').getBoundingClientRect();"
                                "return [r.left, r.top, r.right, r.bottom];") for i in ids]
    return (int(min(r[0] for r in rects)), int(min(r[1] for r in rects)), int(max(r[2] for r in rects)) + 1,
            int(max(r[3] for r in rects)) + 1)


def shoot(cfg_path: Path, out: Path, clip: Path) -> None:
    from motionweb.flows.app.server import Service
    from motionweb.flows.config import load_config
    from selenium import webdriver
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    svc = Service(load_config(cfg_path), port=0, record=False)
    t = threading.Thread(target=svc.run, daemon=True)
    t.start()
    while not svc.server.started:
        time.sleep(0.05)
    opts = webdriver.ChromeOptions()
    opts.binary_location = shutil.which("chromium") or shutil.which("chromium-browser")
    for f in FLAGS:
        opts.add_argument(f)
    drv = webdriver.Chrome(options=opts, service=webdriver.ChromeService(executable_path=shutil.which("chromedriver")))
    try:
        wait = WebDriverWait(drv, 180)
        drv.get(svc.url + "/")
        wait.until(lambda d: len(d.find_elements(By.CSS_SELECTOR, "#catalog tbody tr")) == 6)
        # the search panel: an uploaded clip as the query, its matches registered side by side
        drv.find_element(By.ID, "q-upload").send_keys(str(clip))
        wait.until(lambda d: "upload/" in d.find_element(By.ID, "clip-title").text)
        for fid, value in (("seg-start", "1"), ("seg-end", "2.5")):
            el = drv.find_element(By.ID, fid)
            el.clear()
            el.send_keys(value)
            drv.execute_script(f"document.getElementById('{fid}').dispatchEvent(new Event('change'));")
        drv.find_element(By.ID, "search").click()
        wait.until(lambda d: len(d.find_elements(By.CSS_SELECTOR, "#compare canvas")) > 1)
        wait.until(lambda d: d.find_element(By.ID, "message").text == "")
        time.sleep(1.0)
        left, top, right, _ = union(drv, "player-panel", "results-panel")
        bottom = max(union(drv, "compare")[3], union(drv, "q-pick")[3]) + 8
        save(drv.get_screenshot_as_png(), (left, top, right, bottom), out / "search-upload.png")
        # a retime session of the upload, a keytime added
        drv.execute_script("document.getElementById('retime-panel').scrollIntoView();")
        drv.find_element(By.ID, "rt-open").click()
        wait.until(lambda d: d.execute_script("return !!(rt.result && rt.session && rt.result.session === rt.session.session);"))
        time.sleep(1.0)
        drv.execute_script("document.getElementById('retime-panel').scrollIntoView();")
        save(drv.get_screenshot_as_png(), union(drv, "retime-panel"), out / "retime.png")
        # a warp session of a run of the index toward itself (its flights shaded), with a keytime
        next(r for r in drv.find_elements(By.CSS_SELECTOR, "#catalog tbody tr") if "run_00" in r.text).click()
        wait.until(lambda d: "run/run_00.bvh" in d.find_element(By.ID, "clip-title").text)
        drv.execute_script("document.getElementById('warp-panel').scrollIntoView();")
        drv.find_element(By.ID, "gw-open").click()
        wait.until(lambda d: "cost" in d.find_element(By.ID, "gw-flights").text)
        curve = drv.find_element(By.ID, "gw-curve")
        ActionChains(drv).move_to_element_with_offset(curve, 40, 20).double_click().perform()
        wait.until(lambda d: d.execute_script("return gw.keytimes.length === 1 && !gw.busy && !gw.pending;"))
        time.sleep(1.0)
        drv.execute_script("document.getElementById('warp-panel').scrollIntoView();")
        save(drv.get_screenshot_as_png(), union(drv, "warp-panel"), out / "warp.png")
    finally:
        drv.quit()
        svc.stop()
        t.join(10)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work", type=Path, help="folder for the demo store (kept; default: a temporary one)")
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "img")
    args = ap.parse_args()
    work = args.work or Path(tempfile.mkdtemp(prefix="motionweb-shots-"))
    work.mkdir(parents=True, exist_ok=True)
    os.environ.setdefault("PREFECT_HOME", str(work / "prefect-home"))  # a database of its own
    args.out.mkdir(parents=True, exist_ok=True)
    cfg_path = demo_store(work)
    # the query: a demo walk of another seed, not in the index (its webs are built on demand)
    from motionweb.store.bvh import write_bvh
    from motionweb.store.demo.corpus import generate_clip

    walk, _ = generate_clip("walk", 0, 1234, 30.0)
    write_bvh(walk, work / "my_walk.bvh")
    shoot(cfg_path, args.out, work / "my_walk.bvh")
    if args.work is None:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
