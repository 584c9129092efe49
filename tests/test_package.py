"""The package and the extension: layout rules, Blender's own validator and builder, the CLI."""

import ast
import importlib.util
import pathlib
import subprocess
import sys
import tomllib
import zipfile

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]


def blender_ext_tool():
    """Blender's own extension tool, shipped inside the bpy wheel (found without importing bpy)."""
    spec = importlib.util.find_spec("bpy")
    assert spec is not None, "the bpy module is part of the test environment"
    tool = pathlib.Path(spec.origin).parent / "5.0/scripts/addons_core/bl_pkg/cli/blender_ext.py"
    assert tool.is_file(), tool
    return tool


def run(*args, cwd=ROOT):
    return subprocess.run([sys.executable, *map(str, args)], cwd=cwd, capture_output=True, text=True, timeout=300)


def test_manifest_passes_blenders_validator():
    result = run(blender_ext_tool(), "validate", ROOT)
    assert result.returncode == 0, result.stdout + result.stderr
    manifest = tomllib.loads((ROOT / "blender_manifest.toml").read_text())
    assert manifest["id"] == "mogaface" and manifest["blender_version_min"] == "4.2.0"


def test_extension_zip_has_the_code_and_nothing_else(tmp_path):
    result = run(blender_ext_tool(), "build", "--source-dir", ROOT, "--output-dir", tmp_path)
    assert result.returncode == 0, result.stdout + result.stderr
    (archive,) = tmp_path.glob("mogaface-*.zip")
    names = zipfile.ZipFile(archive).namelist()
    assert "blender_manifest.toml" in names and "__init__.py" in names
    assert "core/flame/model.py" in names and "mogaface_addon/registration.py" in names
    for excluded in ("tests/", "docs/", "bench/", ".venv/", ".git/", "__pycache__/", ".ci/"):
        assert not any(n.startswith(excluded) or f"/{excluded}" in n for n in names), excluded


def package_dirs():
    return sorted(p.parent for p in ROOT.rglob("__init__.py") if not {".venv", "tests", ".git", "build"} & set(p.parts))


def test_pyproject_lists_every_subpackage():
    listed = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    found = {".".join(("mogaface", *d.relative_to(ROOT).parts)) for d in package_dirs()}
    assert found == listed


def test_core_never_imports_blender_or_the_addon_layer():
    offenders = []
    for path in (ROOT / "core").rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                names = [node.module or ""]
                if node.level >= 2 and (node.module or "").split(".")[0] in ("operators", "mogaface_addon"):
                    names.append("mogaface_addon")
            if any(n.split(".")[0] in ("bpy", "bpy_extras", "mathutils", "mogaface_addon", "operators") for n in names):
                offenders.append(f"{path.relative_to(ROOT)}:{node.lineno}")
    assert offenders == []


def test_importing_the_package_loads_no_blender():
    code = "import sys, mogaface, mogaface.core.flame.model; assert 'bpy' not in sys.modules, 'bpy imported'"
    result = run("-c", code, cwd="/")
    assert result.returncode == 0, result.stderr


def test_cli_help_lists_every_command_and_each_has_help():
    from mogaface.core.cli import COMMANDS

    result = run("-m", "mogaface", "--help", cwd="/")
    assert result.returncode == 0, result.stderr
    for name in COMMANDS:
        assert name in result.stdout
    for name in COMMANDS:
        sub = run("-m", "mogaface", name, "--help", cwd="/")
        assert sub.returncode == 0 and "usage:" in sub.stdout, (name, sub.stderr)


@pytest.mark.parametrize("script", ["ensure_venv.sh", "demo.sh", "test.sh"])
def test_readme_scripts_are_strict_bash(script):
    text = (ROOT / "scripts" / script).read_text()
    assert text.startswith("#!/usr/bin/env bash") and "set -euo pipefail" in text
    assert subprocess.run(["bash", "-n", ROOT / "scripts" / script]).returncode == 0
