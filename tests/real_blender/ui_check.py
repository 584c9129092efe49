"""The extension as a user drives it, in the real Blender program with a window (under Xvfb).

Run by scripts/check_real_blender.sh inside Blender (``blender --python ui_check.py -- JSON``).
Stages run from a timer so that Blender's own event loop drives the modal operators (progress,
cancel) for real; each stage asserts its result and the panel is captured into the images folder.
Writes ``results.json`` (every stage, its outcome and timings) and quits; exit code 0 only when
every stage passed.
"""

import json
import os
import pathlib
import shutil
import subprocess
import sys
import time
import traceback

import bpy

ARGS = json.loads(sys.argv[sys.argv.index("--") + 1])
WORK = pathlib.Path(ARGS["work"])
IMAGES = pathlib.Path(ARGS["images"])
MODULE = "bl_ext.user_default.mogaface"
RESULTS = {"stages": [], "blender": bpy.app.version_string, "python": sys.version.split()[0]}


def log(message):
    print(f"[ui-check] {message}", flush=True)


def check(condition, message):
    if not condition:
        raise AssertionError(message)


def check_at_end(condition, message):
    """A measured threshold: the check goes on (every number is printed) and fails at the end."""
    if not condition:
        log(f"FAILED: {message}")
        RESULTS.setdefault("failures", []).append(message)


def check_responsive(longest_block, idle_block, message):
    """The interface kept answering: its longest block under max(1 s, twice the idle window's).
    What the extension does on the interface thread is 3-30 ms an event; the rest of a block is
    Blender's own software-OpenGL redraw, which grows with the machine's load (idle blocks of
    0.2-0.6 s), so a fixed margin over idle failed on load alone. A freeze, work that waits on the
    interface thread, blocked 5.3 s and more before the child processes and worker threads."""
    check_at_end(longest_block < max(1.0, 2.0 * idle_block), message)


def window_and_view():
    window = bpy.context.window_manager.windows[0]
    area = max((a for a in window.screen.areas if a.type == "VIEW_3D"), key=lambda a: a.width * a.height)
    region = next(r for r in area.regions if r.type == "WINDOW")
    return window, area, region


def override():
    window, area, region = window_and_view()
    return bpy.context.temp_override(window=window, area=area, region=region)


def show_panel():
    """A generator step: the 3D View's sidebar on the MoGaFace tab, the splash closed.

    The active tab cannot be set from Python (read-only in 4.3); like a user, click the tabs
    (Blender runs with --enable-event-simulate), top to bottom until MoGaFace is active.
    """
    window, area, _ = window_and_view()
    area.spaces.active.show_region_ui = True
    window.event_simulate(type="ESC", value="PRESS")  # the splash screen
    window.event_simulate(type="ESC", value="RELEASE")
    yield 0.5
    region = next(r for r in area.regions if r.type == "UI")
    x = region.x + region.width - 8  # the tab strip on the sidebar's right edge
    for dy in range(10, region.height, 20):
        if region.active_panel_category == "MoGaFace":
            return
        y = region.y + region.height - dy
        window.event_simulate(type="MOUSEMOVE", value="NOTHING", x=x, y=y)
        window.event_simulate(type="LEFTMOUSE", value="PRESS", x=x, y=y)
        window.event_simulate(type="LEFTMOUSE", value="RELEASE", x=x, y=y)
        yield 0.2
    log(f"the sidebar shows {region.active_panel_category!r}, not MoGaFace")


def shot(name):
    """The whole X screen (Blender's own screenshot reads a black front buffer under Xvfb)."""
    IMAGES.mkdir(parents=True, exist_ok=True)
    path = IMAGES / f"blender-{name}.png"
    subprocess.run(["import", "-window", "root", str(path)], check=True, timeout=60)
    log(f"screenshot {path.name}")


def module(name):
    """One of the extension's modules (imported if nothing imported it yet)."""
    import importlib

    return importlib.import_module(f"{MODULE}.{name}")


def screen_pixels(region):
    """What the screen shows in ``region``: ``(H, W, 3)`` float sRGB in [0, 1], top row first."""
    import numpy as np

    path = WORK / "screen.png"
    subprocess.run(["import", "-window", "root", "-depth", "8", str(path)], check=True, timeout=60)
    image = bpy.data.images.load(str(path))
    width, height = image.size
    pixels = np.zeros(width * height * 4, np.float32)
    image.pixels.foreach_get(pixels)  # a PNG's bytes / 255 (sRGB byte images are read as stored)
    bpy.data.images.remove(image)
    screen = pixels.reshape(height, width, 4)[::-1, :, :3]
    window = bpy.context.window_manager.windows[0]
    top = height - window.y - region.y - region.height
    left = window.x + region.x
    return screen[top:top + region.height, left:left + region.width]


def saved_pixels(image, name):
    """An image saved as Blender saves renders (PNG through the scene's view transform), read back:
    ``(H, W, 4)`` float in [0, 1], top row first, alpha straight."""
    import numpy as np

    path = WORK / f"{name}.png"
    image.save_render(str(path), scene=bpy.context.scene)
    read = bpy.data.images.load(str(path))
    width, height = read.size
    pixels = np.zeros(width * height * 4, np.float32)
    read.pixels.foreach_get(pixels)
    bpy.data.images.remove(read)
    return pixels.reshape(height, width, 4)[::-1]


def srgb(linear):
    import numpy as np

    linear = np.clip(linear, 0.0, 1.0)
    return np.where(linear <= 0.0031308, linear * 12.92, 1.055 * linear ** (1 / 2.4) - 0.055)


def linear(encoded):
    import numpy as np

    return np.where(encoded <= 0.04045, encoded / 12.92, ((encoded + 0.055) / 1.055) ** 2.4)


def over(straight, alpha, behind):
    """The avatar's straight sRGB colour at ``alpha`` over ``behind`` (sRGB), blended in
    scene-linear as Blender blends a premultiplied draw over the view."""
    return srgb(linear(straight) * alpha + (1 - alpha) * linear(behind))


def with_and_without_avatar(head, viewport, area, region):
    """A generator step: the view read back with the avatar, then without it (the head drawn as
    while the avatar is shown); returns ``(shown, behind)``, the avatar shown again."""
    shown = screen_pixels(region)
    setattr(head, viewport.SHOW_PROPERTY, False)
    head.display_type, head.show_in_front = "BOUNDS", True  # the head drawn as while the avatar is shown
    area.tag_redraw()
    yield 1.0
    behind = screen_pixels(region)
    setattr(head, viewport.SHOW_PROPERTY, True)
    area.tag_redraw()
    return shown, behind


def compare(place, got, expected, mask, transform="Standard", required=True):
    """PSNR (dB) of what Blender shows against the core render, over the avatar's pixels (``mask``);
    below 35 dB fails under Standard."""
    import numpy as np

    check(got.shape == expected.shape, f"{place}: shape {got.shape}, expected {expected.shape}")
    check(mask.sum() > 20, f"{place}: only {int(mask.sum())} avatar pixels to compare")
    mse = float(np.mean((got[mask] - expected[mask]) ** 2))
    db = 10 * np.log10(1.0 / max(mse, 1e-12))
    label = place if transform == "Standard" else f"{place} ({transform})"
    line = f"pixels {label}: {db:.1f} dB against the core render"
    print(line, flush=True)
    RESULTS.setdefault("pixels", []).append(line)
    if required:
        check_at_end(db >= 35.0, line)
    return db


def wait_until(condition, timeout, what):
    """A generator step: yields until ``condition()``; counts the timer ticks (Blender is responsive)."""
    start, ticks = time.monotonic(), 0
    while not condition():
        check(time.monotonic() - start < timeout, f"timed out after {timeout} s waiting for {what}")
        ticks += 1
        yield 0.5
    RESULTS.setdefault("ticks", {})[what] = ticks


def stages():
    yield from show_panel()
    yield 2.0
    deps = module("operators.dependencies")
    install = module("operators.install_dependencies")
    prefs = bpy.context.preferences.addons[MODULE].preferences
    missing = deps.missing_modules()
    RESULTS["missing_at_start"] = missing
    if not (missing == [] and ARGS.get("reuse_packages")):  # reuse: re-running the later stages only
        yield from install_stages(deps, install, prefs, missing)
    yield from scene_stages()


def install_stages(deps, install, prefs, missing):
    if ARGS.get("system_torch"):  # Debian's python3-torch (with numpy): the install leaves both alone
        check(missing == ["numba"], f"only numba should be missing beside the system's torch: missing={missing}")
    else:
        check("torch" in missing, f"torch should be missing in a fresh Blender, found missing={missing}")
    shot("1-missing-packages")
    stage("panel offers Install Dependencies")

    # Install Dependencies: runs in the background; Cancel first, then the whole install.
    bpy.context.preferences.system.use_online_access = True
    prefs.torch_index = ARGS["torch_index"]
    site = deps.site_packages(create=True)
    with override():
        check(bpy.ops.mogaface.install_dependencies("INVOKE_DEFAULT") == {"RUNNING_MODAL"}, "install did not start")
    yield from wait_until(lambda: install.current_install() is None or install.current_install().poll().state
                          in ("downloading", "installing"), 1800, "install reaches its download")
    check(install.current_install() is not None, f"install ended early: {install.last_install_progress()}")
    shot("2-installing")
    with override():
        bpy.ops.mogaface.install_dependencies_cancel()
    yield from wait_until(lambda: install.current_install() is None, 120, "install cancel")
    progress = install.last_install_progress()
    check(progress.state == "cancelled", f"cancel gave {progress.state}: {progress.message}")
    check(not os.path.exists(site + ".new") and not os.listdir(site), "a cancelled install left files behind")
    stage("install cancels cleanly")

    started = time.monotonic()
    with override():
        bpy.ops.mogaface.install_dependencies("INVOKE_DEFAULT")
    yield from wait_until(lambda: install.current_install() is None, 3600, "install")
    progress = install.last_install_progress()
    check(progress.state == "done", f"install {progress.state}: {progress.message}")
    size = sum(f.stat().st_size for f in pathlib.Path(site).rglob("*") if f.is_file())
    RESULTS["install"] = {"seconds": round(time.monotonic() - started, 1), "disk_mb": round(size / 1e6),
                          "message": progress.message,
                          "packages": progress.packages}
    check(deps.missing_modules() == [], f"still missing after the install: {deps.missing_modules()}")
    for name in ("numpy", "torch"):  # never replaced where Blender's Python has them
        check(not any(p.lower().startswith(name) for p in progress.packages) or name in missing,
              f"{name} installed although Blender's Python has one: {progress.packages}")
    yield from show_panel()
    yield 1.0
    shot("3-packages-ready")
    stage("Install Dependencies")


def scene_stages():

    # Import the capture and a head into the startup file, default cube and all, as a new user does.
    cube = bpy.data.objects.get("Cube")
    with override():
        check(bpy.ops.mogaface.import_capture(filepath=ARGS["capture"]) == {"FINISHED"}, "import capture")
        check(bpy.ops.mogaface.import_head(filepath=ARGS["head"]) == {"FINISHED"}, "import head")
    head = bpy.context.active_object
    check(len([o for o in bpy.data.objects if o.type == "CAMERA"]) >= 3, "the capture's cameras are missing")
    check(cube is None or not cube.visible_get(), "the default cube around the head is still shown")
    yield from head_framing(head)
    stage("import capture and head: the head framed, the default cube hidden")

    # Train through the modal operator with the panel's default preset, as a user does: progress
    # (the bar's text fits the sidebar), Cancel (checkpoint), Resume to the end, a linked, scored avatar.
    train = module("operators.train")
    run = str(WORK / "run")
    settings = bpy.context.scene.mogaface
    settings.capture_folder, settings.run_folder = ARGS["capture"], run
    preset = type(settings).bl_rna.properties["preset"].default
    check(settings.preset == preset, f"the scene's preset {settings.preset!r} is not the default {preset!r}")
    RESULTS["training"] = {"preset": preset, "steps": ARGS["steps"], "bar_texts": []}
    with override():
        result = bpy.ops.mogaface.train("INVOKE_DEFAULT", capture=ARGS["capture"], run=run, preset=settings.preset,
                                        steps=ARGS["steps"], resume="NEW")
        check(result == {"RUNNING_MODAL"}, f"train gave {result}: {train.last_progress()}")
    yield from wait_until(lambda: note_bar(train) or train.current_worker() is None
                          or train.current_worker().progress.step >= 5, 1800, "training progress")
    check(train.current_worker() is not None, f"training ended early: {train.last_progress()}")
    yield from show_panel()
    yield from wait_until(lambda: note_bar(train) or train.current_worker() is None
                          or train.current_worker().progress.eta_s is not None, 600, "training's first ETA")
    yield 1.0
    shot("4-training")
    progress_fits_sidebar(train.last_progress())
    with override():
        bpy.ops.mogaface.train_cancel()
    yield from wait_until(lambda: train.current_worker() is None, 300, "training cancel")
    check(train.last_progress().state == "cancelled", f"cancel gave {train.last_progress()}")
    check(os.path.exists(os.path.join(run, "checkpoints", "latest")), "no checkpoint after cancel")
    stage(f"train with the default preset ({preset}), cancel")
    with override():
        bpy.ops.mogaface.train("INVOKE_DEFAULT", capture=ARGS["capture"], run=run, resume="RESUME")
    yield from wait_until(lambda: note_bar(train) or train.current_worker() is None, 1800, "resumed training")
    check(train.last_progress().state == "done", f"resume gave {train.last_progress()}")
    check(settings.avatar_file == os.path.join(run, "avatar.pt"), f"the Avatar field holds {settings.avatar_file!r}")
    metrics = json.loads((WORK / "run" / "metrics_train_end.json").read_text())
    RESULTS["training"].update(metrics={k: metrics.get(k) for k in ("frames", "psnr", "ssim", "lpips", "not_scored")},
                               message=train.last_progress().message)
    check("lpips" in metrics and "not_scored" not in metrics, f"the run was not fully scored: {metrics}")
    log(f"training: {RESULTS['training']}")
    stage("resume to the end: the avatar linked and scored (PSNR, SSIM, LPIPS)")

    # The avatar: load, render a frame and a keyed animation, export.
    with override():
        check(bpy.ops.mogaface.import_head(filepath=os.path.join(run, "head.npz") if os.path.exists(
            os.path.join(run, "head.npz")) else os.path.join(run, "head.pkl")) == {"FINISHED"}, "import run head")
        head = bpy.context.active_object
    idle = [time.monotonic()]  # first the same window doing nothing: its redraws alone (software GL)

    def idle_tick():
        idle.append(time.monotonic())
        return 0.02 if idle[-1] - idle[0] < 3.0 else None

    bpy.app.timers.register(idle_tick, first_interval=0.02)
    yield 3.5
    idle_block = max(b - a for a, b in zip(idle, idle[1:]))
    ticks, linked = [time.monotonic()], []

    def tick():  # Blender's event loop runs a timer every 20 ms when nothing blocks it
        ticks.append(time.monotonic())
        if not linked and "mogaface_avatar_path" in head:
            linked.append(ticks[-1])
        return 0.02 if "done" not in RESULTS.get("load_avatar", {}) else None

    bpy.app.timers.register(tick, first_interval=0.02)
    with override():
        result = bpy.ops.mogaface.load_avatar("INVOKE_DEFAULT", filepath=run, target=head.name)
        check(result in ({"RUNNING_MODAL"}, {"FINISHED"}), f"load avatar gave {result}")
    RESULTS["load_avatar"] = {}
    yield from wait_until(lambda: "mogaface_avatar_path" in head, 300, "load avatar")
    yield 2.0  # the first viewport draw of the avatar starts its render thread: timed apart
    link = linked[0] if linked else ticks[-1]
    gaps = [(b - a, a) for a, b in zip(ticks, ticks[1:])]
    RESULTS["load_avatar"] = {
        "done": True, "seconds": round(link - ticks[0], 2), "idle_longest_block_s": round(idle_block, 3),
        "longest_ui_block_s": round(max(g for g, at in gaps if at < link), 3),
        "longest_block_in_2_s_after_s": round(max([g for g, at in gaps if at >= link] or [0.0]), 3),
        "blocks_over_0.1_s": [[round(g, 3), round(at - ticks[0], 2)] for g, at in gaps if g > 0.1]}
    log(f"Load Avatar: {RESULTS['load_avatar']}")
    check_responsive(RESULTS["load_avatar"]["longest_ui_block_s"], idle_block,
                     f"Load Avatar froze the UI: {RESULTS['load_avatar']}")
    scene = bpy.context.scene
    camera = next(o for o in scene.objects if o.get("mogaface_resolution") is not None)
    check(module("operators.import_capture").apply_render_settings(scene, camera), "capture camera")
    scene.render.resolution_percentage = 400  # the capture's 48 px, four times larger
    with override():
        check(bpy.ops.mogaface.render_frame(head=head.name) == {"FINISHED"}, "render frame")
    yield from render_frame_pixels(head, camera)
    with override():
        head.data.shape_keys.key_blocks[1].value = 0.0
        head.data.shape_keys.key_blocks[1].keyframe_insert("value", frame=1)
        head.data.shape_keys.key_blocks[1].value = 1.0
        head.data.shape_keys.key_blocks[1].keyframe_insert("value", frame=2)
    # Render Animation runs in the background like training: progress in the status bar, Esc cancels.
    frames = WORK / "frames"
    render_ops = module("operators.render")
    with override():
        result = bpy.ops.mogaface.render_animation("INVOKE_DEFAULT", head=head.name, frame_start=1, frame_end=2,
                                                   directory=str(frames))
        check(result == {"RUNNING_MODAL"}, f"render animation gave {result}")
    yield from wait_until(lambda: render_ops.current_render_job() is None, 600, "render animation")
    check(len(list(frames.glob("*.png"))) == 2, f"expected 2 frames in {frames}")
    for frame, path in zip((1, 2), sorted(frames.glob("*.png"))):
        core = core_render(head, camera, frame, transparent=False)
        read = bpy.data.images.load(str(path))
        import numpy as np

        pixels = np.zeros(read.size[0] * read.size[1] * 4, np.float32)
        read.pixels.foreach_get(pixels)
        shape = (read.size[1], read.size[0], 4)
        bpy.data.images.remove(read)
        compare(f"Render Animation frame {frame}", pixels.reshape(shape)[::-1, :, :3], core.rgb, core.alpha > 1 / 255)
    with override():
        ply = WORK / "avatar.ply"
        check(bpy.ops.mogaface.export_ply(filepath=str(ply), head=head.name) == {"FINISHED"} and ply.exists(),
              "export ply")
    images = [i for i in bpy.data.images if i.name.startswith("MoGaFace ")]
    check(images, "no rendered image in bpy.data.images")
    yield from show_panel()
    yield 1.0
    shot("5-avatar")
    stage("load avatar, render frame and animation, export")
    yield from avatar_in_scene_stages(head)
    yield from disable_stages(head)
    yield from improve_tracking_stages(head, run)
    if ARGS.get("footage"):
        yield from drive_from_footage_stages(head)
        yield from track_footage_stages(head)
    bpy.ops.wm.save_userpref()


def head_framing(head):
    """A generator step: the head's share of the 3D view after Import Capture, from the screen's
    pixels (the view with the head, without it); at least a quarter of the view's height."""
    import numpy as np

    _, area, region = window_and_view()
    area.tag_redraw()
    yield 1.0
    shot("3b-imported")
    shown = screen_pixels(region)
    head.hide_set(True)
    area.tag_redraw()
    yield 1.0
    hidden = screen_pixels(region)
    head.hide_set(False)
    area.tag_redraw()
    rows, columns = np.nonzero(np.abs(shown - hidden).max(axis=2) > 0.05)
    check(len(rows) > 0, "the head is not in the view after Import Capture")
    height, width = rows.max() - rows.min() + 1, columns.max() - columns.min() + 1
    RESULTS["head_in_view_px"] = {"head": [int(width), int(height)], "view": [region.width, region.height]}
    log(f"the head after Import Capture: {RESULTS['head_in_view_px']}")
    check_at_end(height >= 0.25 * region.height, f"the head is small in the view: {RESULTS['head_in_view_px']}")
    yield 0.5


def note_bar(train) -> bool:
    """Record each new text of the training's progress bar (False: a wait goes on)."""
    worker = train.current_worker()
    if worker is not None:
        texts = RESULTS["training"]["bar_texts"]
        text = worker.progress.bar_text()
        if not texts or texts[-1] != text:
            texts.append(text)
    return False


def progress_fits_sidebar(progress):
    """The progress bar's text and the line below it, measured with Blender's own UI font, fit the
    sidebar at its width (Blender cuts the middle out of a text that does not)."""
    import blf

    _, area, _ = window_and_view()
    sidebar = next(r for r in area.regions if r.type == "UI")
    scale = bpy.context.preferences.system.ui_scale
    style = bpy.context.preferences.ui_styles[0].widget
    blf.size(0, style.points * scale)
    room = sidebar.width - 40 * scale  # the panel's margins and the tab strip
    widths = {text: round(blf.dimensions(0, text)[0]) for text in (progress.bar_text(), progress.detail_text())}
    RESULTS["training"]["sidebar"] = {"width": sidebar.width, "room": round(room), "texts": widths}
    log(f"progress texts in the sidebar: {RESULTS['training']['sidebar']}")
    check_at_end(all(width <= room for width in widths.values()), f"a progress text is cut: {widths}, room {room}")
    check(any("compiling" in text for text in RESULTS["training"]["bar_texts"]) or
          RESULTS["training"]["bar_texts"][0].startswith("step 0"), "no 'compiling' before the first steps")


def disable_stages(head):
    """Disable the extension: F12 renders the scene without the avatar (compositing on or off,
    the same picture), the head is its textured mesh, no thread of the extension is left; then
    enable it: the avatar is back in F12."""
    import threading

    import numpy as np

    scene = bpy.context.scene
    scene.frame_set(2)
    with_avatar = render_still("f12-before-disable", compositing=True)
    bpy.ops.preferences.addon_disable(module=MODULE)
    yield 1.0
    deadline = time.monotonic() + 10
    while [t for t in threading.enumerate() if t.name.startswith("mogaface-")] and time.monotonic() < deadline:
        yield 0.2
    threads = [t.name for t in threading.enumerate() if t.name.startswith("mogaface-")]
    check(not threads, f"threads of the extension left after disabling it: {threads}")
    check((head.display_type, head.show_in_front, head.hide_render) == ("TEXTURED", False, False),
          f"the head after disabling: {head.display_type}, in front {head.show_in_front}, "
          f"hidden from renders {head.hide_render}")
    scene.frame_set(1)
    composited = render_still("f12-disabled", compositing=True)
    plain = render_still("f12-disabled-plain", compositing=False)
    difference = float(np.abs(composited - plain).max())
    RESULTS["disabled_f12_max_difference"] = round(difference, 4)
    check(difference <= 2 / 255, f"F12 with the extension disabled is not the scene alone (max {difference:.3f})")
    shot("10-disabled")
    bpy.ops.preferences.addon_enable(module=MODULE)
    yield 1.0
    scene.frame_set(2)
    again = render_still("f12-enabled-again", compositing=True)
    check(head.display_type == "BOUNDS", f"the head after enabling again: {head.display_type} "
          f"(still marked suspended: {'mogaface_suspended' in head})")
    back = float(np.abs(again - with_avatar).max())
    RESULTS["enabled_again_f12_max_difference"] = round(back, 4)
    check(back <= 2 / 255, f"F12 after enabling again differs from before disabling (max {back:.3f})")
    stage("disable: F12 without the avatar, the head as a mesh, no threads; enable: the avatar back")


def render_still(name, compositing):
    """F12 to ``WORK/NAME.png`` and read back: ``(H, W, 3)``, bottom row first."""
    import numpy as np

    scene = bpy.context.scene
    scene.render.use_compositing = compositing
    scene.render.filepath = str(WORK / name)
    scene.render.image_settings.file_format = "PNG"
    with override():
        bpy.ops.render.render(write_still=True)
    image = bpy.data.images.load(str(WORK / f"{name}.png"))
    pixels = np.array(image.pixels[:], np.float32).reshape(image.size[1], image.size[0], -1)[..., :3]
    bpy.data.images.remove(image)
    return pixels


def core_render(head, camera, frame, transparent):
    """The core's own render of what ``head`` shows at ``frame`` (its keys) from ``camera``."""
    scene = bpy.context.scene
    avatar_head = module("operators.avatar_head")
    request = avatar_head.head_request(scene, head, avatar_head.camera_of(scene, camera, head), frame,
                                       transparent=transparent, keyed=True)
    return module("core.for_blender.render").render(request)


def render_frame_pixels(head, camera):
    """Render Frame's image saved through the view transform: under Standard the core render."""
    scene = bpy.context.scene
    frame = scene.frame_current
    image = bpy.data.images[module("core.for_blender.render").render_image_name(camera.name, frame)]
    core = core_render(head, camera, frame, transparent=False)
    mask = core.alpha > 1 / 255
    check(scene.view_settings.view_transform == "Standard", "Import Capture did not set Standard")
    compare("Render Frame", saved_pixels(image, "render-frame-standard")[..., :3], core.rgb, mask)
    area = module("operators.images").image_editor_area(bpy.context.window_manager)[0]
    RESULTS["render_frame_editor"] = None if area is None else [area.width, area.height]
    check(area is not None and area.width >= 400 and area.height >= 300, f"Image Editor {RESULTS['render_frame_editor']}")
    yield 1.0
    shot("8-render-frame-standard")
    scene.view_settings.view_transform = "AgX"
    compare("Render Frame", saved_pixels(image, "render-frame-agx")[..., :3], core.rgb, mask, "AgX", required=False)
    yield 1.0
    shot("8-render-frame-agx")
    scene.view_settings.view_transform = "Standard"
    yield from close_render_windows()


def close_render_windows():
    """Close the render windows Render Frame/Animation opened (without a window manager, Xvfb
    puts them over the main window)."""
    for window in list(bpy.context.window_manager.windows)[1:]:
        with bpy.context.temp_override(window=window):
            bpy.ops.wm.window_close()
    yield 1.0


def improve_tracking_stages(head, run):
    """Improve Tracking from the window: the refiner trained in a child process, the head keyed."""
    improving = module("operators.improve_tracking")
    with override():
        result = bpy.ops.mogaface.improve_tracking(run=run, target=head.name, passes=1)
        check(result == {"RUNNING_MODAL"}, f"improve tracking gave {result}: {improving.last_progress()}")
    yield from wait_until(lambda: improving.current_worker() is None or improving.current_worker().progress.step >= 1,
                          600, "improve tracking progress")
    yield from show_panel()
    shot("7-improving-tracking")
    yield from wait_until(lambda: improving.current_worker() is None, 900, "improve tracking")
    check(improving.last_progress().state == "done", f"improve tracking gave {improving.last_progress()}")
    folder = bpy.context.scene.mogaface.tracking_folder
    check(folder == os.path.join(run, "refined_tracking", "flame_param"), f"the head was keyed from {folder}")
    curves = module("operators.animation").id_fcurves(head.data.shape_keys)
    keyed = {len(c.keyframe_points) for c in curves if "key_blocks" in c.data_path}
    check(keyed == {len(list(pathlib.Path(folder).glob("*.npz")))}, f"keys per expression: {keyed}")
    stage("improve tracking (the refiner trained first), the head keyed")


def follow_footage_job(what, screenshot):
    """A generator step: a footage job to its end, the interface's longest block meanwhile timed
    against the idle window's (the job runs in a child process: Blender must never wait for it)."""
    footage = module("operators.footage")
    ticks = [time.monotonic()]

    def tick():  # while the child runs; the import and keying after it are not the tracking
        if footage.current_worker() is None:
            return None
        ticks.append(time.monotonic())
        return 0.02

    bpy.app.timers.register(tick, first_interval=0.02)
    yield from wait_until(lambda: footage.current_worker() is None or footage.current_worker().progress.step >= 1,
                          600, f"{what} progress")
    yield from show_panel()
    taken = time.monotonic()
    shot(screenshot)  # the check's own screenshot holds the main thread: its gap is not Blender's
    taken = (taken, time.monotonic())
    yield from wait_until(lambda: footage.current_worker() is None, 900, what)
    check(footage.last_progress().state == "done", f"{what} gave {footage.last_progress()}")
    idle = RESULTS["load_avatar"]["idle_longest_block_s"]
    gaps = [b - a for a, b in zip(ticks, ticks[1:]) if b < taken[0] or a > taken[1]]
    longest = max(gaps, default=0.0)
    RESULTS.setdefault("footage", {})[what] = {"seconds": round(ticks[-1] - ticks[0], 1),
                                               "longest_ui_block_s": round(longest, 3), "idle_block_s": idle}
    log(f"{what}: {RESULTS['footage'][what]}")
    check_responsive(longest, idle, f"{what} froze the UI: {RESULTS['footage'][what]}")


def drive_from_footage_stages(head):
    """Drive from Footage on the trained avatar's head with a second clip: the keys are the tracker's
    parameters at the scene's frame rate, and Render Frame shows the performance (two frames, each the
    core render of its keys, differing as the performance does)."""
    import numpy as np

    scene = bpy.context.scene
    camera = next(o for o in scene.objects if o.get("mogaface_resolution") is not None)
    check(module("operators.import_capture").apply_render_settings(scene, camera), "capture camera")
    scene.frame_set(scene.frame_start)
    yield 1.5  # the avatar's first draws through the new camera (the check's change) before the job is timed
    out = WORK / "performance"
    with override():
        result = bpy.ops.mogaface.drive_from_footage("INVOKE_DEFAULT", filepath=ARGS["performance"], out=str(out),
                                                     target=head.name, tolerance=0.001, size=160, fit_steps=60)
        check(result == {"RUNNING_MODAL"}, f"drive from footage gave {result}")
    yield from follow_footage_job("drive from footage", "12-drive-from-footage")
    performance = module("core.for_blender.tracking").read_tracking(out)
    n_expr = performance.params["expr"].shape[1]
    worst = 0.0
    for index, frame in enumerate(performance.frames):
        scene.frame_set(int(frame))
        keys = head.data.shape_keys.key_blocks
        worst = max(worst, float(np.abs(np.array([keys[i + 1].value for i in range(n_expr)])
                                        - performance.params["expr"][index]).max()))
        for name, (prop, _) in module("core.for_blender.head_rig").POSE_PROPERTIES.items():
            worst = max(worst, float(np.abs(np.array(head[prop]) - performance.params[name][index]).max()))
    fps = scene.render.fps / scene.render.fps_base
    RESULTS["footage"]["drive"] = {"frames": len(performance.frames), "scene_fps": fps, "keys_worst_error": worst}
    check(worst < 1e-4, f"the keyed channels differ from the tracker's parameters by {worst}")
    expr = performance.params["expr"]
    first, other = 0, int(np.argmax(np.abs(expr - expr[0]).sum(1)))  # the frame furthest from the first
    renders = []
    for index in (first, other):
        frame = int(performance.frames[index])
        scene.frame_set(frame)
        with override():
            check(bpy.ops.mogaface.render_frame(head=head.name) == {"FINISHED"}, "render frame of the performance")
        image = bpy.data.images[module("core.for_blender.render").render_image_name(camera.name, frame)]
        core = core_render(head, camera, frame, transparent=False)
        got = saved_pixels(image, f"drive-frame-{frame}")[..., :3]
        compare(f"Drive from Footage frame {frame}", got, core.rgb, core.alpha > 1 / 255)
        renders.append((got, core.rgb))
    shown_change = float(np.abs(renders[0][0] - renders[1][0]).mean())
    core_change = float(np.abs(renders[0][1] - renders[1][1]).mean())
    RESULTS["footage"]["drive"].update(frames_compared=[int(performance.frames[first]), int(performance.frames[other])],
                                       shown_change=round(shown_change, 5), core_change=round(core_change, 5))
    log(f"drive: {RESULTS['footage']['drive']}")
    check(shown_change > 1e-3 and abs(shown_change - core_change) < 0.25 * core_change,
          f"the rendered frames do not change as the performance does: {RESULTS['footage']['drive']}")
    yield from close_render_windows()
    stage("Drive from Footage: the performance keyed at the scene's rate, rendered as it plays")


def track_footage_stages(avatar_head):
    """Track Footage of a phone clip: the camera with the movie behind it, the head keyed; the head's
    landmarks read back from Blender (evaluated mesh, Blender's camera) reproject onto the detections
    as the tracker's own fit does, and its F12 silhouette covers the person's mask."""
    import numpy as np
    from bpy_extras.object_utils import world_to_camera_view
    from mathutils import Vector

    scene = bpy.context.scene
    viewport = module("operators.handlers.viewport")
    setattr(avatar_head, viewport.SHOW_PROPERTY, False)
    for obj in scene.objects:
        if obj.type == "MESH":
            obj.hide_set(True)
            obj.hide_render = True
    earlier = bpy.data.collections.get("MoGaFace Capture")
    if earlier is not None:
        earlier.name = "MoGaFace Capture (trained)"
        earlier.hide_viewport = True
    out = WORK / "tracked"
    with override():
        result = bpy.ops.mogaface.track_footage("INVOKE_DEFAULT", filepath=ARGS["footage"], out=str(out), size=160,
                                                fit_steps=100)
        check(result == {"RUNNING_MODAL"}, f"track footage gave {result}")
    yield from follow_footage_job("track footage", "13-tracking-footage")
    report = json.loads((out / "tracking.json").read_text())
    head, camera = bpy.context.view_layer.objects.active, scene.camera
    check(module("operators.handlers.heads").is_head(head), "Track Footage left no head active")
    background = camera.data.background_images[0]
    check(background.source == "MOVIE_CLIP" and background.clip is not None, "the footage is not behind the camera")
    capture = module("core.data.capture").Capture.open(out)
    faces = np.array([p.vertices[:] for p in head.data.polygons])
    embedding = module("core.track.mediapipe_embedding").model_mediapipe_embedding(faces)
    mesh_of_ibug = module("core.track.mediapipe_ibug68").IBUG68_FROM_MESH
    row = {int(m): i for i, m in enumerate(embedding.ibug)}
    ibug = [i for i, m in enumerate(mesh_of_ibug) if int(m) in row]
    at = np.array([row[int(mesh_of_ibug[i])] for i in ibug])  # the embedding's rows of those iBUG points
    points = module("core.flame.landmarks").LandmarkEmbedding(embedding.faces[at], embedding.barycentric[at],
                                                              embedding.ibug[at])
    detected = module("core.data.landmarks").read_landmarks(out, capture.cameras, len(capture.timesteps))["cam00"]
    model = module("core.for_blender.head_rig").load_head_model(head["mogaface_model_path"])
    width, height = scene.render.resolution_x, scene.render.resolution_y
    errors = {"blender_vs_core": [], "blender_vs_detected": [], "core_vs_detected": []}
    for t in sorted({0, len(capture.timesteps) // 2, len(capture.timesteps) - 1}):
        scene.frame_set(t + 1)
        evaluated = head.evaluated_get(bpy.context.evaluated_depsgraph_get())
        mesh = evaluated.to_mesh()
        co = np.zeros(len(mesh.vertices) * 3, np.float32)
        mesh.vertices.foreach_get("co", co)
        evaluated.to_mesh_clear()
        world = [head.matrix_world @ Vector(p) for p in points.positions(co.reshape(-1, 3).astype(np.float64), faces)]
        shown = np.array([[v.x * width, (1 - v.y) * height]
                          for v in (world_to_camera_view(scene, camera, p) for p in world)])
        params = capture.flame_params(t)
        vertices = model(**{k: v for k, v in params.items() if k != "static_offset"})
        core, _ = capture.camera_at("cam00", t).project(points.positions(vertices, model.arrays.faces))
        seen = detected[t, ibug, 2] > 0
        errors["blender_vs_core"].append(float(np.linalg.norm(shown - core, axis=1).mean()))
        errors["blender_vs_detected"].append(float(np.linalg.norm(shown - detected[t, ibug, :2], axis=1)[seen].mean()))
        errors["core_vs_detected"].append(float(np.linalg.norm(core - detected[t, ibug, :2], axis=1)[seen].mean()))
    reprojection = {k: round(float(np.mean(v)), 3) for k, v in errors.items()}
    reprojection["tracker_report_px"] = report["reprojection_px"]["mean"]
    RESULTS["footage"]["track"] = {"frames": report["frames"], "lost": report["lost_frames"],
                                   "landmarks_px": reprojection}
    check_at_end(reprojection["blender_vs_core"] < 0.5
                 and abs(reprojection["blender_vs_detected"] - reprojection["core_vs_detected"]) < 0.5,
                 f"the head in Blender does not reproject as the tracker's fit: {reprojection}")
    # pixels: the head's silhouette in an F12 render (Workbench) against the person's mask of that frame
    engine, transparent = scene.render.engine, scene.render.film_transparent
    scene.render.engine, scene.render.film_transparent = "BLENDER_WORKBENCH", True
    scene.render.resolution_percentage = 100  # the capture's own size, as its masks
    head.hide_set(False)
    head.hide_render = False
    t = len(capture.timesteps) // 2
    scene.frame_set(t + 1)
    scene.render.filepath = str(WORK / "tracked-head")
    with override():
        bpy.ops.render.render(write_still=True)
    image = bpy.data.images.load(str(WORK / "tracked-head.png"))
    alpha = np.array(image.pixels[:], np.float32).reshape(image.size[1], image.size[0], 4)[::-1, :, 3]
    bpy.data.images.remove(image)
    scene.render.engine, scene.render.film_transparent = engine, transparent
    frame = capture.timestep_frame(t)
    _, mask = capture.load_image(frame)
    person, drawn = np.asarray(mask).reshape(alpha.shape) > 0.5, alpha > 0.5
    iou = float((person & drawn).sum() / max((person | drawn).sum(), 1))
    RESULTS["footage"]["track"]["silhouette_iou"] = round(iou, 3)
    log(f"track footage: {RESULTS['footage']['track']}")
    check_at_end(iou > 0.6, f"the tracked head's silhouette covers the person's mask poorly: IoU {iou:.3f}")
    window, area, _ = window_and_view()
    area.spaces.active.region_3d.view_perspective = "CAMERA"
    head.display_type = "WIRE"  # the footage seen through the tracked head, as a user checks the fit
    area.tag_redraw()
    yield from show_panel()
    yield 1.0
    shot("14-tracked-head-over-footage")
    head.display_type = "TEXTURED"
    stage("Track Footage: the camera, the keyed head over the movie, read back from Blender")


def viewport_pixels(head, viewport):
    """The still viewport read back from the screen: at the region's own size, and under Standard
    the core render of the view's camera over what the view shows without the avatar."""
    import numpy as np

    yield from close_render_windows()
    _, area, region = window_and_view()
    region_3d = area.spaces.active.region_3d

    def full_size():
        area.tag_redraw()
        states = [s for s in viewport._views.values() if s.image is not None]
        return states and all(s.future is None for s in viewport._views.values()) and \
            (states[0].image.width, states[0].image.height) == (region.width, region.height)

    yield from wait_until(full_size, 300, "the still viewport at the region's size")
    request, _ = viewport.viewport_request(head, np.array(region_3d.view_matrix), np.array(region_3d.window_matrix),
                                           (region.width, region.height), bpy.context.scene.frame_current)
    core = module("core.for_blender.render").render(request)
    alpha = np.where(core.alpha >= viewport.OPAQUE_ALPHA, 1.0, core.alpha)[..., None]
    straight = np.divide(core.rgb, core.alpha[..., None], out=np.zeros_like(core.rgb), where=core.alpha[..., None] > 0)
    RESULTS["viewport_size"] = [region.width, region.height]
    overlay = area.spaces.active.overlay
    # overlays off: the colours alone (required); on, for the record: the head's bounds box, drawn
    # in front while the avatar is shown, lies under the avatar (the grid and lines as well)
    for show_overlays, transform in ((False, "Standard"), (True, "Standard"), (True, "AgX")):
        overlay.show_overlays = show_overlays
        bpy.context.scene.view_settings.view_transform = transform
        area.tag_redraw()
        yield 1.0
        shown, behind = yield from with_and_without_avatar(head, viewport, area, region)
        expected = over(straight, alpha, behind)
        place = "viewport" if not show_overlays else "viewport with overlays"
        compare(place, shown, expected, core.alpha > 1 / 255, transform, required=not show_overlays)
        if show_overlays:
            yield 1.0
            shot(f"9-viewport-{transform.lower()}")
    bpy.context.scene.view_settings.view_transform = "Standard"
    area.tag_redraw()
    yield 0.5


def gpu_draw(state, splats, view, projection, size, frame):
    """The GPU draw of ``splats`` into an offscreen ``size``² buffer: ``(H, W, 4)`` scene-linear
    premultiplied, top row first."""
    import gpu
    import numpy as np

    try:
        offscreen = gpu.types.GPUOffScreen(size, size, format="RGBA32F")
    except TypeError:  # a Blender without the format argument: 8 bits per channel
        offscreen = gpu.types.GPUOffScreen(size, size)
    with offscreen.bind():
        gpu.state.active_framebuffer_get().clear(color=(0.0, 0.0, 0.0, 0.0), depth=1.0)
        check(state.draw(splats, view, projection, size, size, frame), "the GPU draw did not draw")
    pixels = np.array(offscreen.texture_color.read().to_list(), np.float32).reshape(size, size, 4)
    offscreen.free()
    return pixels[::-1]


def gpu_fps(gpu_splats, core_gpu, splats, view, projection, count, size=512, repeats=10):
    """Frames per second of the GPU draw of ``count`` Gaussians (the avatar's, repeated with a
    shift) into a ``size``² buffer: with a sort, colours and upload every frame (playback, orbit)
    and the draw alone (a still view); each timed loop ends by reading a pixel back (the GPU done)."""
    import gpu
    import numpy as np

    reps = -(-count // len(splats.opacities))
    rng = np.random.default_rng(0)
    shift = np.repeat(rng.normal(0.0, 0.002, (reps, 3)), len(splats.opacities), axis=0)[:count]
    many = core_gpu.PosedSplats(
        (np.tile(splats.means, (reps, 1))[:count] + shift).astype(np.float32),
        np.tile(splats.covariances, (reps, 1))[:count], np.tile(splats.opacities, reps)[:count],
        np.tile(splats.colors, (reps,) + (1,) * (splats.colors.ndim - 1))[:count], f"{splats.key}x{count}")
    state = gpu_splats.GpuSplats()
    offscreen = gpu.types.GPUOffScreen(size, size)
    result = {"gaussians": count, "size": size}
    with offscreen.bind():
        for label, frames in (("fps_sort_every_frame", range(repeats)), ("fps_draw_only", [0] * repeats)):
            state.draw(many, view, projection, size, size, -1)
            offscreen.texture_color.read()
            start = time.perf_counter()
            for frame in frames:
                gpu.state.active_framebuffer_get().clear(color=(0.0, 0.0, 0.0, 0.0), depth=1.0)
                state.draw(many, view, projection, size, size, frame)
            gpu.state.active_framebuffer_get().read_color(0, 0, 1, 1, 4, 0, "FLOAT")
            result[label] = round(repeats / (time.perf_counter() - start), 2)
    offscreen.free()
    return result


def gpu_draw_pixels(head, viewport):
    """The GPU draw of the still view at 512² against the core render of the same view (under
    Standard, premultiplied sRGB over black, over the avatar's pixels): at least 30 dB; then
    its frames per second at 30k and 100k Gaussians."""
    import numpy as np

    gpu_splats = module("operators.handlers.gpu_draw")
    core_gpu = module("core.for_blender.splat_buffers")
    render = module("core.for_blender.render")
    check(gpu_splats.program() is not None, f"the GPU draw cannot run: {gpu_splats.unavailable()}")
    _, area, _ = window_and_view()
    region_3d = area.spaces.active.region_3d
    size, frame = 512, bpy.context.scene.frame_current
    view_matrix, projection = np.array(region_3d.view_matrix), np.array(region_3d.window_matrix)
    request, view = viewport.viewport_request(head, view_matrix, projection, (size, size), frame)
    core = render.render(request)
    splats = core_gpu.posed_splats(request.avatar_path, request.params)
    drawn = gpu_draw(gpu_splats.GpuSplats(), splats, view, projection, size, frame)
    expected = render.srgb_from_blender(render.blender_rgba(core))
    got = render.srgb_from_blender(drawn)
    mask = (core.alpha > 1 / 255) | (drawn[..., 3] > 1 / 255)
    db = compare("viewport GPU", got, expected, mask, required=False)
    RESULTS["gpu_alpha_max_difference"] = round(float(np.abs(drawn[..., 3] - core.alpha).max()), 4)
    check_at_end(db >= 30.0, f"pixels viewport GPU: {db:.1f} dB against the core render (below 30 dB)")
    yield 0.5
    RESULTS["gpu_fps"] = [gpu_fps(gpu_splats, core_gpu, splats, view, projection, count) for count in (30000, 100000)]
    RESULTS["gpu_fps_load_average_1min"] = round(os.getloadavg()[0], 2)
    log(f"GPU draw fps (software GL): {RESULTS['gpu_fps']} (load {RESULTS['gpu_fps_load_average_1min']})")
    yield 0.5


def live_gpu_pixels(head, viewport):
    """The view switched to the GPU draw, read back from the screen (overlays off, Standard)
    against the core render of the view over what the view shows without the avatar."""
    import numpy as np

    _, area, region = window_and_view()
    region_3d = area.spaces.active.region_3d
    area.spaces.active.overlay.show_overlays = False
    setattr(head, viewport.DRAW_PROPERTY, "GPU")

    def drawn():
        area.tag_redraw()
        return any(s.gpu is not None and s.gpu.order.packed is not None for s in viewport._views.values())

    yield from wait_until(drawn, 120, "the GPU draw in the viewport")
    area.tag_redraw()
    yield 1.0
    shown, behind = yield from with_and_without_avatar(head, viewport, area, region)
    yield 1.0  # the avatar drawn again before the screenshot below
    request, _ = viewport.viewport_request(head, np.array(region_3d.view_matrix), np.array(region_3d.window_matrix),
                                           (region.width, region.height), bpy.context.scene.frame_current)
    core = module("core.for_blender.render").render(request)
    alpha = core.alpha[..., None]
    straight = np.divide(core.rgb, alpha, out=np.zeros_like(core.rgb), where=alpha > 0)
    expected = over(straight, alpha, behind)
    db = compare("viewport GPU, live in the window", shown, expected, core.alpha > 1 / 255, required=False)
    check_at_end(db >= 30.0, f"pixels viewport GPU, live in the window: {db:.1f} dB (below 30 dB)")
    shot("9-viewport-gpu")
    setattr(head, viewport.DRAW_PROPERTY, "BOTH")
    area.spaces.active.overlay.show_overlays = True
    area.tag_redraw()
    yield 0.5


class Profile:
    """Seconds spent in named functions of the extension while it is active: where a block of the
    interface goes (the sort and colours, the texture upload, the draw calls, the CPU image's
    upload); what is left of a block is Blender's own redraw and the GL work it waits for."""

    def __init__(self):
        gpu_splats = module("operators.handlers.gpu_draw")
        viewport = module("operators.handlers.viewport")
        core_gpu = module("core.for_blender.splat_buffers")
        self.targets = [(viewport, "draw_head", "draw handler, in all"),
                        (viewport, "update_view", "CPU image: request"),
                        (viewport, "textures", "CPU image: upload"),
                        (viewport, "draw_image", "CPU image: upload and draw"),
                        (gpu_splats.GpuSplats, "draw", "GPU draw: sort, upload, draw"),
                        (core_gpu.SplatOrder, "update", "GPU draw: sort and colours"),
                        (gpu_splats.Posing, "latest", "GPU draw: posing hand-over"),
                        (module("operators.handlers.heads"), "_update_heads", "head meshes re-posed")]
        self.seconds, self.calls, self.saved = {}, {}, []

    def __enter__(self):
        for owner, name, label in self.targets:
            original = getattr(owner, name)
            self.saved.append((owner, name, original))
            setattr(owner, name, self._timed(original, label))
        return self

    def _timed(self, function, label):
        def timed(*args, **kwargs):
            start = time.perf_counter()
            try:
                return function(*args, **kwargs)
            finally:
                self.seconds[label] = self.seconds.get(label, 0.0) + time.perf_counter() - start
                self.calls[label] = self.calls.get(label, 0) + 1

        return timed

    def __exit__(self, *exc):
        for owner, name, original in reversed(self.saved):
            setattr(owner, name, original)

    def report(self, events: int) -> dict:
        """Milliseconds per event (a frame change, an orbit step) in each function, and its calls."""
        return {label: {"ms_per_event": round(1000 * seconds / max(events, 1), 1), "calls": self.calls[label]}
                for label, seconds in sorted(self.seconds.items(), key=lambda item: -item[1])}


def timed_loop(changes, settle=0.1):
    """A generator step: apply each change, redraw, and time Blender's event loop (a 20 ms timer);
    returns the gaps between ticks."""
    _, area, _ = window_and_view()
    ticks, done = [time.monotonic()], []

    def tick():
        ticks.append(time.monotonic())
        return None if done else 0.02

    bpy.app.timers.register(tick, first_interval=0.02)
    for change in changes:
        change()
        area.tag_redraw()
        yield settle
    done.append(True)
    yield 0.2
    return [b - a for a, b in zip(ticks, ticks[1:])]


def orbit_blocks(head, viewport):
    """Orbit the view around the avatar with Draw: Both, step by step: the longest block of the
    interface and where it goes (:class:`Profile`), as scrubbing below."""
    from mathutils import Quaternion

    _, area, _ = window_and_view()
    region_3d = area.spaces.active.region_3d
    setattr(head, viewport.DRAW_PROPERTY, "BOTH")
    start = region_3d.view_rotation.copy()
    steps = 12

    def turn(index):
        return lambda: setattr(region_3d, "view_rotation", Quaternion((0.0, 0.0, 1.0), 0.05 * index) @ start)

    with Profile() as profile:
        gaps = yield from timed_loop([turn(i + 1) for i in range(steps)])
    region_3d.view_rotation = start
    idle = RESULTS.get("load_avatar", {}).get("idle_longest_block_s", 0.0)
    RESULTS["orbit"] = {"steps": steps, "longest_ui_block_s": round(max(gaps), 3), "idle_longest_block_s": idle,
                        "mean_block_s": round(sum(g for g in gaps if g > 0.05) / max(1, sum(g > 0.05 for g in gaps)), 3),
                        "profile": profile.report(steps), "load_average_1min": round(os.getloadavg()[0], 2)}
    log(f"orbit with Draw: Both: {RESULTS['orbit']}")
    check_responsive(max(gaps), idle, f"orbiting froze the UI: {RESULTS['orbit']}")
    area.tag_redraw()
    yield 1.0


def scrub_blocks(head, viewport):
    """Scrub the timeline: the longest block of Blender's event loop (a 20 ms timer) while frames
    change, each change followed by a redraw, with the draw a user has (Both: on a software OpenGL,
    the CPU image rendered off the interface thread), then with the GPU draw forced (for the
    record: under software OpenGL it rasterises every Gaussian on the interface thread). Both is
    held to :func:`check_responsive`, as Load Avatar is."""
    _, area, _ = window_and_view()
    scene = bpy.context.scene
    frames = list(range(scene.frame_start, min(scene.frame_end, scene.frame_start + 11) + 1))
    idle = RESULTS.get("load_avatar", {}).get("idle_longest_block_s", 0.0)
    RESULTS["software_opengl"] = module("operators.handlers.gpu_draw").software_renderer()
    for mode in ("BOTH", "GPU"):
        setattr(head, viewport.DRAW_PROPERTY, mode)
        changes = [lambda frame=frame: scene.frame_set(frame) for frame in frames + frames[::-1]]
        with Profile() as profile:  # new frames (posed on the worker thread), then cached ones
            gaps = yield from timed_loop(changes)
        result = {"frame_changes": len(changes), "seconds": round(sum(gaps), 2),
                  "longest_ui_block_s": round(max(gaps), 3), "idle_longest_block_s": idle,
                  "blocks_over_0.1_s": sum(g > 0.1 for g in gaps), "profile": profile.report(len(changes)),
                  "load_average_1min": round(os.getloadavg()[0], 2)}
        RESULTS[f"scrub_{mode.lower()}"] = result
        log(f"scrubbing with Draw: {mode}: {result}")
        if mode == "BOTH":
            check_responsive(max(gaps), idle, f"scrubbing froze the UI: {result}")
        scene.frame_set(frames[0])
        yield 1.0
    setattr(head, viewport.DRAW_PROPERTY, "BOTH")
    area.tag_redraw()
    yield 0.5


def avatar_in_scene_stages(head):
    """The avatar drawn live in the viewport at two keyed frames, then in an F12 render."""
    import numpy as np

    viewport = module("operators.handlers.viewport")
    for other in bpy.context.scene.objects:  # the first imported head stands where the avatar is
        if other.type == "MESH" and other != head:
            other.hide_set(True)
            other.hide_render = True
    setattr(head, viewport.SHOW_PROPERTY, True)
    window, area, _ = window_and_view()
    with override():
        bpy.ops.object.select_all(action="DESELECT")
        head.select_set(True)
        bpy.context.view_layer.objects.active = head
        bpy.ops.view3d.view_selected()
    keys = []
    for frame in (1, 2):
        bpy.context.scene.frame_set(frame)

        def drawn():
            area.tag_redraw()  # the draw handler runs on redraws; it renders off the main thread
            images = [state.image for state in viewport._views.values() if state.image is not None]
            return bool(images) and images[0].key not in keys and all(
                state.future is None for state in viewport._views.values())

        yield from wait_until(drawn, 300, f"the viewport's avatar at frame {frame}")
        image = next(state.image for state in viewport._views.values() if state.image is not None)
        check(float(image.rgba[3::4].max()) > 0.5, f"the viewport image at frame {frame} is empty")
        keys.append(image.key)
        yield 1.0
        shot(f"6-viewport-frame{frame}")
    stage("the avatar in the viewport follows the keys")
    yield from viewport_pixels(head, viewport)
    yield from gpu_draw_pixels(head, viewport)
    yield from live_gpu_pixels(head, viewport)
    stage("the GPU draw of the Gaussians against the core render, and its speed")
    yield from scrub_blocks(head, viewport)
    stage("scrubbing the timeline never blocks the interface")
    yield from orbit_blocks(head, viewport)
    stage("orbiting the avatar with Draw: Both, timed stage by stage")

    scene = bpy.context.scene
    capture_camera = next(o for o in scene.objects if o.get("mogaface_resolution") is not None)
    check(module("operators.import_capture").apply_render_settings(scene, capture_camera), "capture camera")
    scene.render.resolution_percentage = 400  # the capture's 48 px, four times larger
    with override():
        check(bpy.ops.mogaface.setup_render_layer() == {"FINISHED"}, "avatar in renders")

    plain = render_still("f12-without-avatar", compositing=False)  # the head mesh is hidden from renders
    with_avatar = render_still("f12", compositing=True)
    changed = np.abs(with_avatar - plain).max(-1) > 0.1
    RESULTS["f12_avatar_pixels"] = int(changed.sum())
    check(changed.mean() > 0.01, f"the F12 render does not show the avatar ({int(changed.sum())} pixels differ)")
    core = core_render(head, scene.camera, scene.frame_current, transparent=True)
    straight = np.divide(core.rgb, core.alpha[..., None], out=np.zeros_like(core.rgb), where=core.alpha[..., None] > 0)
    a = core.alpha[..., None]
    expected = over(straight, a, plain[::-1])  # render_still's rows are bottom first
    compare("F12 composite", with_avatar[::-1], expected, core.alpha > 1 / 255)
    result = saved_pixels(bpy.data.images["Render Result"], "f12-render-result")
    compare("F12 Render Result", result[..., :3], expected, core.alpha > 1 / 255)
    stage(f"F12 render with the avatar ({scene.render.engine})")


def stage(name):
    RESULTS["stages"].append({"stage": name, "ok": True, "t": round(time.monotonic() - T0, 1)})
    log(f"ok: {name}")


T0 = time.monotonic()
RUNNER = stages()


def step():
    try:
        return next(RUNNER)
    except StopIteration:
        RESULTS["ok"] = not RESULTS.get("failures")
    except Exception:  # noqa: BLE001 - every failure ends the check with its traceback
        RESULTS["ok"] = False
        RESULTS["error"] = traceback.format_exc()
        log(RESULTS["error"])
        try:
            shot("failure")
        except Exception:  # noqa: BLE001
            pass
    (WORK / "results.json").write_text(json.dumps(RESULTS, indent=1))
    bpy.ops.wm.quit_blender()
    return None


if __name__ == "__main__":
    shutil.rmtree(IMAGES / "failure.png", ignore_errors=True)
    bpy.app.timers.register(step, first_interval=2.0)
