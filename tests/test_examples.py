"""The bundled USD example is what its script writes, and the README's USD workflow runs on it as a user runs it."""

import importlib.util

import numpy as np
from pxr import Sdf, Usd, UsdGeom

from conftest import EXAMPLE, warp_stokes

CAGE, SKIN = "/Arm/Rig/Cage", "/Arm/Geo/Skin"


def test_bundled_asset_is_what_its_script_writes(tmp_path):
    spec = importlib.util.spec_from_file_location("make_usd_asset", EXAMPLE / "make_usd_asset.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    fresh = Usd.Stage.Open(str(module.write(tmp_path / "arm.usda")))
    bundled = Usd.Stage.Open(str(EXAMPLE / "arm.usda"))
    for path in (SKIN, CAGE):
        a, b = UsdGeom.Mesh(fresh.GetPrimAtPath(path)), UsdGeom.Mesh(bundled.GetPrimAtPath(path))
        assert a.GetPointsAttr().GetTimeSamples() == b.GetPointsAttr().GetTimeSamples()
        np.testing.assert_array_equal(np.asarray(a.GetPointsAttr().Get(1)), np.asarray(b.GetPointsAttr().Get(1)))
        np.testing.assert_array_equal(np.asarray(a.GetFaceVertexIndicesAttr().Get()),
                                      np.asarray(b.GetFaceVertexIndicesAttr().Get()))
    assert np.asarray(bundled.GetPrimAtPath(CAGE).GetAttribute("points").Get(24)).shape == (58, 3)


def test_readme_usd_workflow(tmp_path):
    # the installed command in subprocesses: the bind and animate commands' runs as a user runs them
    result = warp_stokes("bind", EXAMPLE / "arm.usda", "--cage-prim", CAGE, "-o", tmp_path / "arm_usd.npz",
                         "--resolution", "24", "--device", "cpu")
    assert result.returncode == 0, result.stderr
    out = tmp_path / "arm_bend_layer.usda"
    result = warp_stokes("animate", tmp_path / "arm_usd.npz", EXAMPLE / "arm.usda", "--cage-prim", CAGE, "-o", out,
                         "--device", "cpu")
    assert result.returncode == 0, result.stderr
    assert "24 frames (1 to 24) at 24 fps" in result.stdout
    layer = Sdf.Layer.FindOrOpen(str(out))
    assert len(layer.subLayerPaths) == 1 and not layer.subLayerPaths[0].startswith("/")
    stage = Usd.Stage.Open(str(out))
    skin = UsdGeom.Mesh(stage.GetPrimAtPath(SKIN))
    assert skin.GetPointsAttr().GetTimeSamples() == [float(t) for t in range(1, 25)]
    assert skin.GetNormalsAttr().GetNumTimeSamples() == 24
    asset = Usd.Stage.Open(str(EXAMPLE / "arm.usda"))
    rest = np.asarray(UsdGeom.Mesh(asset.GetPrimAtPath(SKIN)).GetPointsAttr().Get())
    first = np.asarray(skin.GetPointsAttr().Get(1))
    diagonal = np.linalg.norm(np.ptp(rest, axis=0))
    assert np.abs(first - rest).max() < 1e-5 * diagonal  # frame 1 is the rest pose, in the skin's local space
    assert np.abs(np.asarray(skin.GetPointsAttr().Get(24)) - rest).max() > 0.05 * diagonal  # and it moves
