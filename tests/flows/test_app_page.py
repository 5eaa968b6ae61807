"""The page of `motionweb app` in a real headless Chromium (Debian's chromium + chromium-driver,
driven by selenium): load it, open a clip, search a segment, see the result rows, and check that
the canvases animate, with no console errors. Skips with the reason where Chromium cannot run."""

from __future__ import annotations

import shutil
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from motionweb.flows.app.server import Service
from motionweb.flows.config import load_config

selenium = pytest.importorskip("selenium", reason="selenium is not installed (pip install -e '.[dev]')")
from selenium import webdriver  # noqa: E402
from selenium.webdriver.common.action_chains import ActionChains  # noqa: E402
from selenium.webdriver.common.by import By  # noqa: E402
from selenium.webdriver.support import expected_conditions as ec  # noqa: E402
from selenium.webdriver.support.ui import WebDriverWait  # noqa: E402

FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
         "--disable-component-update", "--disable-sync", "--no-first-run", "--window-size=1700,1100"]


@pytest.fixture(scope="module")
def browser(tmp_path_factory):
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    driver_bin = shutil.which("chromedriver")
    if not chromium or not driver_bin:
        pytest.skip("Chromium or chromedriver not found (apt-get install chromium chromium-driver)")
    opts = webdriver.ChromeOptions()
    opts.binary_location = chromium
    for f in FLAGS:
        opts.add_argument(f)
    opts.add_argument(f"--user-data-dir={tmp_path_factory.mktemp('chromium-profile')}")
    opts.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    try:
        drv = webdriver.Chrome(options=opts, service=webdriver.ChromeService(executable_path=driver_bin))
    except Exception as exc:  # no display libraries, a broken install, ...
        pytest.skip(f"Chromium could not start: {str(exc).splitlines()[0]}")
    drv.set_page_load_timeout(60)
    yield drv
    drv.quit()


@pytest.fixture(scope="module")
def service(app_store, tmp_path_factory, monkeypatch_module):
    monkeypatch_module.setenv("MOTIONWEB_APP_DIR", str(tmp_path_factory.mktemp("disc")))
    svc = Service(load_config(app_store), port=0, record=False)
    t = threading.Thread(target=svc.run, daemon=True)
    t.start()
    deadline = time.monotonic() + 30
    while not svc.server.started and time.monotonic() < deadline:
        time.sleep(0.05)
    yield svc
    svc.stop()
    t.join(10)


@pytest.fixture(scope="module")
def monkeypatch_module():
    mp = pytest.MonkeyPatch()
    yield mp
    mp.undo()


def canvas_data(drv, cid: str) -> str:
    return drv.execute_script(f"return document.getElementById('{cid}').toDataURL();")


def set_segment(drv, start: str, end: str) -> None:
    """Type the query segment into the page's start and end fields, as a user does."""
    for fid, value in (("seg-start", start), ("seg-end", end)):
        el = drv.find_element(By.ID, fid)
        el.clear()
        el.send_keys(value)
        drv.execute_script(f"document.getElementById('{fid}').dispatchEvent(new Event('change'));")


def test_page_opens_a_clip_searches_and_animates(browser, service) -> None:
    drv = browser
    wait = WebDriverWait(drv, 60)
    drv.get(service.url + "/")
    wait.until(lambda d: len(d.find_elements(By.CSS_SELECTOR, "#catalog tbody tr")) == 6)
    assert "generation" in drv.find_element(By.ID, "status").text
    # filter the catalog by name
    drv.find_element(By.ID, "f-name").send_keys("walk")
    wait.until(lambda d: len(d.find_elements(By.CSS_SELECTOR, "#catalog tbody tr")) == 3)
    row = next(r for r in drv.find_elements(By.CSS_SELECTOR, "#catalog tbody tr") if "walk_00" in r.text)
    row.click()
    wait.until(ec.element_to_be_clickable((By.ID, "search")))
    assert "walk/walk_00.bvh" in drv.find_element(By.ID, "clip-title").text
    # the player animates: the canvas changes between two moments
    first = canvas_data(drv, "view")
    time.sleep(0.5)
    assert canvas_data(drv, "view") != first
    # a segment and a search
    set_segment(drv, "1", "2.5")
    drv.find_element(By.ID, "search").click()
    wait.until(lambda d: len(d.find_elements(By.CSS_SELECTOR, "#results tbody tr")) > 2)
    rows = drv.find_elements(By.CSS_SELECTOR, "#results tbody tr")
    assert "walk/walk_00.bvh" in rows[0].text and all("walk/" in r.text for r in rows)
    links = rows[1].find_elements(By.TAG_NAME, "a")
    assert [a.text for a in links] == ["seg", "reg", "seg.glb", "reg.glb"] and "/bvh" in links[0].get_attribute("href")
    assert "/glb?registered=true" in links[3].get_attribute("href")
    # registered matches play side by side
    wait.until(lambda d: len(d.find_elements(By.CSS_SELECTOR, "#compare canvas")) == len(rows))
    time.sleep(0.3)
    a = drv.execute_script("return [...document.querySelectorAll('#compare canvas')].map(c => c.toDataURL());")
    time.sleep(0.5)
    b = drv.execute_script("return [...document.querySelectorAll('#compare canvas')].map(c => c.toDataURL());")
    assert all(x != y for x, y in zip(a, b, strict=True))
    blank = drv.execute_script("const c = document.createElement('canvas'); c.width = 420; c.height = 240;"
                               "const x = c.getContext('2d'); x.fillStyle = '#fff'; x.fillRect(0, 0, 420, 240);"
                               "return c.toDataURL();")
    assert canvas_data(drv, "graph") != blank and canvas_data(drv, "warps") != blank
    errors = [e for e in drv.get_log("browser") if e["level"] == "SEVERE"]
    assert not errors, errors
    assert drv.find_element(By.ID, "message").text == ""


def test_space_panel_plays_the_motion_for_a_dragged_target(browser, service, app_space) -> None:
    """The motion-space panel: the sampled cloud drawn, a target dragged across it, the synthesized
    motion in the player changing with it, the distance shown for a target outside."""
    drv = browser
    wait = WebDriverWait(drv, 60)
    drv.get(service.url + "/")
    wait.until(lambda d: "examples" in d.find_element(By.ID, "space-info").text)
    assert drv.find_element(By.ID, "space").get_attribute("value") == app_space
    assert "hidden" not in drv.find_element(By.ID, "space-height-box").get_attribute("class")  # 3-D: height slider
    cloud = drv.find_element(By.ID, "cloud")
    ActionChains(drv).move_to_element(cloud).click_and_hold().move_by_offset(-20, 10).release().perform()
    wait.until(lambda d: "achieved" in d.find_element(By.ID, "space-result").text)
    assert "synthesized" in drv.find_element(By.ID, "clip-title").text
    first = canvas_data(drv, "view")
    time.sleep(0.5)
    assert canvas_data(drv, "view") != first  # it plays
    drv.find_element(By.ID, "play").click()  # pause, then compare the same frame of two motions

    def frame0() -> tuple[str, str]:
        drv.execute_script("state.time = 0;")
        time.sleep(0.2)
        return canvas_data(drv, "view"), drv.execute_script("return JSON.stringify(state.pose.positions.slice(0, 60));")

    before, pos_before = frame0()
    text = drv.find_element(By.ID, "space-result").text
    cloud_before = canvas_data(drv, "cloud")
    (ActionChains(drv).move_to_element(cloud).click_and_hold().move_by_offset(25, -10).move_by_offset(25, -10)
     .move_by_offset(20, 5).release().perform())
    wait.until(lambda d: d.find_element(By.ID, "space-result").text != text)
    time.sleep(0.5)  # the last (debounced) request of the drag answered
    wait.until(lambda d: not d.execute_script("return space.busy || space.pending;"))
    after, pos_after = frame0()
    assert pos_after != pos_before and after != before  # another motion in the player
    assert canvas_data(drv, "cloud") != cloud_before  # the target moved on the cloud
    # a target far outside the sampled region: projected, its distance shown
    drv.execute_script("space.target = space.info.hi.map((v) => v + 1.0); drawCloud(); synthesizeSoon(0);")
    wait.until(lambda d: "outside the sampled region" in d.find_element(By.ID, "space-result").text)
    assert " cm from the target" in drv.find_element(By.ID, "space-result").text
    errors = [e for e in drv.get_log("browser") if e["level"] == "SEVERE"]
    assert not errors, errors
    assert drv.find_element(By.ID, "message").text == ""


def test_page_plays_a_glb_in_its_own_loader(browser, service, app_store) -> None:
    """The page's GLB loader (no 3-D library) reads a clip's GLB download: the joint positions it
    composes from the file's nodes and samplers equal FK, and the player draws them over time."""
    from motionweb.flows.app.engine import clip_id
    from motionweb.store.formats import read_motion
    from motionweb.store.kinematics import forward_kinematics

    drv = browser
    wait = WebDriverWait(drv, 60)
    drv.get(service.url + "/")
    wait.until(lambda d: len(d.find_elements(By.CSS_SELECTOR, "#catalog tbody tr")) == 6)
    cfg = load_config(app_store)
    path = "walk/walk_01.bvh"
    drv.set_script_timeout(60)
    pose = drv.execute_async_script(
        "const done = arguments[arguments.length - 1];"
        f"openGlbUrl('/api/clips/{clip_id(path)}/glb').then((p) => done(p), (e) => done({{error: String(e)}}));")
    assert "error" not in pose, pose
    m = read_motion(Path(cfg.corpus.path) / path, unit="m")
    got = np.array(pose["positions"]).reshape(pose["frames"], len(pose["parents"]), 3)
    np.testing.assert_allclose(got, forward_kinematics(m)[0] * m.metres(), atol=1e-4)
    assert pose["joints"] == list(m.skeleton.names) and pose["parents"] == m.skeleton.parents.tolist()
    assert pose["rate"] == pytest.approx(m.fps, rel=1e-5)
    assert "walk_01.glb" in drv.find_element(By.ID, "clip-title").text
    first = canvas_data(drv, "view")
    time.sleep(0.5)
    assert canvas_data(drv, "view") != first


# ---------------------------------------------------------------- the Retime panel (retime sessions)

def retimed_positions(drv) -> str:
    return drv.execute_script("return JSON.stringify(rt.result && rt.result.pose.positions.slice(0, 300));")


def settle(drv, wait) -> None:
    """Wait until the panel's last (debounced) edit is answered."""
    time.sleep(0.3)
    wait.until(lambda d: not d.execute_script("return rt.busy || rt.pending;"))


def test_retime_panel_edits_play_and_redraw(browser, service) -> None:
    """The Retime panel (static/retime.js, MPS06 sessions): open a session on the player's clip, set
    the duration and drag a keytime (the retimed motion that plays changes), change gravity (the
    plots are redrawn), with no console errors."""
    drv = browser
    wait = WebDriverWait(drv, 120)
    drv.get(service.url + "/")
    wait.until(lambda d: len(d.find_elements(By.CSS_SELECTOR, "#catalog tbody tr")) == 6)
    row = next(r for r in drv.find_elements(By.CSS_SELECTOR, "#catalog tbody tr") if "walk_00" in r.text)
    row.click()
    wait.until(lambda d: "walk/walk_00.bvh" in d.find_element(By.ID, "clip-title").text)
    drv.find_element(By.ID, "rt-open").click()
    wait.until(lambda d: "prepared in" in d.find_element(By.ID, "rt-info").text)
    wait.until(lambda d: d.execute_script("return rt.result !== null;"))
    settle(drv, wait)
    # the retimed motion plays beside the original
    first = canvas_data(drv, "rt-retimed")
    time.sleep(0.4)
    assert canvas_data(drv, "rt-retimed") != first
    assert "shortest reachable" in drv.find_element(By.ID, "rt-reach").text
    # a duration: another motion plays
    before = retimed_positions(drv)
    el = drv.find_element(By.ID, "rt-duration")
    el.clear()
    el.send_keys("3.1")
    drv.execute_script("document.getElementById('rt-duration').dispatchEvent(new Event('change'));")
    wait.until(lambda d: d.execute_script("return rt.result.duration_out;") == pytest.approx(3.1, abs=1e-6))
    settle(drv, wait)
    after_duration = retimed_positions(drv)
    assert after_duration != before
    # a keytime added (double-click) and dragged on the timeline: another motion again
    tl = drv.find_element(By.ID, "rt-timeline")
    w = tl.size["width"]
    ActionChains(drv).move_to_element_with_offset(tl, -w // 2 + int(0.4 * w), 0).double_click().perform()
    wait.until(lambda d: d.execute_script("return rt.keytimes.length;") == 1)
    settle(drv, wait)
    with_key = retimed_positions(drv)
    kt_before = drv.execute_script("return rt.keytimes[0][1];")
    (ActionChains(drv).move_to_element_with_offset(tl, -w // 2 + int(0.4 * w), 0).click_and_hold()
     .move_by_offset(30, 0).move_by_offset(30, 0).release().perform())
    wait.until(lambda d: d.execute_script("return rt.keytimes[0][1];") > kt_before + 0.1)
    settle(drv, wait)
    wait.until(lambda d: d.execute_script("return JSON.stringify(rt.result.pose.positions.slice(0, 300));") != with_key)
    assert drv.execute_script("return rt.result.duration_out;") == pytest.approx(3.1, abs=1e-6)
    # gravity: a new session, the plots redrawn
    plots = {c: canvas_data(drv, c) for c in ("rt-timing", "rt-torques", "rt-polygon")}
    sid = drv.execute_script("return rt.session.session;")
    el = drv.find_element(By.ID, "rt-gx")
    el.clear()
    el.send_keys("4")
    drv.find_element(By.ID, "rt-apply").click()
    wait.until(lambda d: d.execute_script("return rt.session.session;") != sid)
    settle(drv, wait)
    wait.until(lambda d: d.execute_script("return rt.result.session;") != sid)
    assert canvas_data(drv, "rt-timing") != plots["rt-timing"] or canvas_data(drv, "rt-torques") != plots["rt-torques"]
    assert drv.execute_script("return rt.session.physics.gravity;") == [4, -9.81, 0]
    # a clip of the user's own: a BVH uploaded from a file input, retimed in the panel
    clip = next(Path(service.cfg.corpus.path).rglob("walk_01.bvh"))
    drv.find_element(By.ID, "rt-upload").send_keys(str(clip))
    wait.until(lambda d: d.execute_script("return rt.session && rt.session.path;") == "upload/walk_01.bvh")
    settle(drv, wait)
    wait.until(lambda d: d.execute_script("return rt.result.session;") == d.execute_script("return rt.session.session;"))
    errors = [e for e in drv.get_log("browser") if e["level"] == "SEVERE"]
    assert not errors, errors
    assert drv.find_element(By.ID, "message").text == ""


def test_warp_panel_warps_the_clip_and_a_keytime_changes_it(browser, service) -> None:
    """The guided warp panel (static/warp.js, HDP07 sessions): the player's clip warped toward
    itself, the warp curve drawn, a keytime added on it changes the motion that plays."""
    drv = browser
    wait = WebDriverWait(drv, 120)
    drv.get(service.url + "/")
    wait.until(lambda d: len(d.find_elements(By.CSS_SELECTOR, "#catalog tbody tr")) == 6)
    next(r for r in drv.find_elements(By.CSS_SELECTOR, "#catalog tbody tr") if "walk_00" in r.text).click()
    wait.until(lambda d: "walk/walk_00.bvh" in d.find_element(By.ID, "clip-title").text)
    drv.find_element(By.ID, "gw-open").click()
    wait.until(lambda d: "cost" in d.find_element(By.ID, "gw-flights").text)
    wait.until(lambda d: not d.execute_script("return gw.busy || gw.pending;"))
    first = canvas_data(drv, "gw-view")
    time.sleep(0.4)
    assert canvas_data(drv, "gw-view") != first  # it plays
    before = drv.execute_script("return JSON.stringify(gw.result.pose.positions.slice(0, 300));")
    curve = drv.find_element(By.ID, "gw-curve")
    ActionChains(drv).move_to_element_with_offset(curve, 40, 20).double_click().perform()
    wait.until(lambda d: d.execute_script("return gw.keytimes.length;") == 1)
    time.sleep(0.3)
    wait.until(lambda d: not d.execute_script("return gw.busy || gw.pending;"))
    wait.until(lambda d: d.execute_script("return JSON.stringify(gw.result.pose.positions.slice(0, 300));") != before)
    # the original plays beside the warped motion, and the curve marks each flight's ratio
    first = canvas_data(drv, "gw-original")
    time.sleep(0.4)
    assert canvas_data(drv, "gw-original") != first
    assert drv.execute_script("return gw.original.pose.frames;") == drv.execute_script("return gw.session.original.frames;")
    # dragging the keytime changes the motion that plays
    added = drv.execute_script("return JSON.stringify(gw.keytimes);")
    before = drv.execute_script("return JSON.stringify(gw.result.pose.positions.slice(0, 300));")
    ActionChains(drv).move_to_element_with_offset(curve, 40, 20).click_and_hold().move_by_offset(-25, 30) \
        .move_by_offset(-25, 30).release().perform()
    wait.until(lambda d: d.execute_script("return JSON.stringify(gw.keytimes);") != added)
    assert drv.execute_script("return gw.keytimes.length;") == 1
    time.sleep(0.3)
    wait.until(lambda d: not d.execute_script("return gw.busy || gw.pending;"))
    wait.until(lambda d: d.execute_script("return JSON.stringify(gw.result.pose.positions.slice(0, 300));") != before)
    errors = [e for e in drv.get_log("browser") if e["level"] == "SEVERE"]
    assert not errors, errors
    assert drv.find_element(By.ID, "message").text == ""


def test_an_uploaded_clip_is_searched_from_the_page(browser, service, tmp_path: Path) -> None:
    """A BVH of the user's own (a demo walk not in the index) uploaded through the search panel's
    file input plays in the player, is picked as the query, and its segment is searched: the
    service builds its webs on demand (KG04 §3.3) and the matches are listed, no console error."""
    from motionweb.store.bvh import write_bvh
    from motionweb.store.demo.corpus import generate_clip

    walk, _ = generate_clip("walk", 0, 1234, 30.0)
    write_bvh(walk, tmp_path / "my_walk.bvh")
    drv = browser
    wait = WebDriverWait(drv, 120)
    drv.get(service.url + "/")
    wait.until(lambda d: len(d.find_elements(By.CSS_SELECTOR, "#catalog tbody tr")) == 6)
    drv.find_element(By.ID, "q-upload").send_keys(str(tmp_path / "my_walk.bvh"))
    wait.until(lambda d: "upload/my_walk.bvh" in d.find_element(By.ID, "clip-title").text)
    uid = drv.execute_script("return state.clip.id;")
    assert uid.startswith("up-") and drv.find_element(By.ID, "q-pick").get_attribute("value") == uid
    set_segment(drv, "1", "2.5")
    drv.find_element(By.ID, "search").click()
    wait.until(lambda d: len(d.find_elements(By.CSS_SELECTOR, "#results tbody tr")) > 1)
    rows = drv.find_elements(By.CSS_SELECTOR, "#results tbody tr")
    assert f"file:{uid}/my_walk.bvh" in rows[0].text and any("walk/" in r.text for r in rows[1:])
    wait.until(lambda d: len(d.find_elements(By.CSS_SELECTOR, "#compare canvas")) > 1)  # registered, played
    wait.until(lambda d: d.find_element(By.ID, "message").text == "")
    # picking an indexed clip, then the upload again from the list
    next(r for r in drv.find_elements(By.CSS_SELECTOR, "#catalog tbody tr") if "run_00" in r.text).click()
    wait.until(lambda d: "run/run_00.bvh" in d.find_element(By.ID, "clip-title").text)
    assert drv.find_element(By.ID, "q-pick").get_attribute("value") == ""
    from selenium.webdriver.support.ui import Select

    Select(drv.find_element(By.ID, "q-pick")).select_by_value(uid)
    wait.until(lambda d: "upload/my_walk.bvh" in d.find_element(By.ID, "clip-title").text)
    errors = [e for e in drv.get_log("browser") if e["level"] == "SEVERE"]
    assert not errors, errors
    assert drv.find_element(By.ID, "message").text == ""
