import shutil
import subprocess

import numpy as np
import pytest

import warp_stokes as ws
from warp_stokes.cli import main
from conftest import EXAMPLE, cli


def test_bind_then_deform(tmp_path, capsys, device):
    out = tmp_path / "arm.npz"
    rc = main(["bind", str(EXAMPLE / "arm.obj"), str(EXAMPLE / "arm_cage.obj"), "-o", str(out),
               "--resolution", "16", "--device", device])
    printed = capsys.readouterr().out
    assert rc == 0 and out.exists()
    for key in ("grid", "interior", "iterations", "partition of unity", "linear precision", "seconds"):
        assert key in printed
    b = ws.load_binding(out, device=device)
    assert b.weights.shape == (2089, 58) and b.settings["resolution"] == 16

    # moving the whole cage moves the mesh rigidly
    cage = ws.load_surface(EXAMPLE / "arm_cage.obj")
    moved = tmp_path / "moved_cage.obj"
    with open(moved, "w") as fh:
        fh.writelines(f"v {x + 5} {y} {z}\n" for x, y, z in cage.vertices)
        fh.writelines(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in cage.faces)
    deformed = tmp_path / "arm_moved.obj"
    assert main(["deform", str(out), str(moved), "-o", str(deformed), "--device", device]) == 0
    result = ws.load_surface(deformed)
    np.testing.assert_allclose(result.vertices, b.mesh_vertices + [5, 0, 0], atol=1e-3)


@pytest.mark.parametrize(
    "args, message",
    [
        (["bind", "missing.obj", str(EXAMPLE / "arm_cage.obj")], "missing.obj: no such file"),
        (["bind", str(EXAMPLE / "arm.obj"), str(EXAMPLE / "arm.obj")], "arm.obj: the cage is not closed"),
        (["bind", str(EXAMPLE / "arm.obj"), str(EXAMPLE / "arm_cage.obj"), "--resolution", "2"], "resolution"),
        (["bind", str(EXAMPLE / "arm.obj"), str(EXAMPLE / "arm_cage.obj"), "--device", "tpu"], "device 'tpu'"),
    ],
)
def test_errors_are_one_line_and_exit_non_zero(tmp_path, capsys, args, message):
    rc = main(args + ["-o", str(tmp_path / "out.npz")] if args[0] == "bind" else args)
    err = capsys.readouterr().err.strip().splitlines()
    assert rc != 0
    assert len(err) == 1 and err[0].startswith("warp-stokes: error: ") and message in err[0]
    assert not (tmp_path / "out.npz").exists()


def test_an_unconverged_bind_exits_non_zero(tmp_path, capsys, device):
    # weights that break partition of unity and linear precision are never written: one line, exit code 1, and
    # advice that holds (the Jacobi CG was still converging when its limit of 2 stopped it)
    out = tmp_path / "arm.npz"
    rc = main(["bind", str(EXAMPLE / "arm.obj"), str(EXAMPLE / "arm_cage.obj"), "-o", str(out),
               "--resolution", "16", "--device", device, "--solver", "jacobi", "--max-iterations", "2"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1 and not out.exists() and len(err) == 1, err
    assert err[0].startswith("warp-stokes: error: the solver could not bring partition of unity and linear "
                             "precision within 1e-05") and err[0].endswith("while still converging (residual "
                                                                           + err[0].split("(residual ")[-1])
    assert "no weights were returned" in err[0] and err[0].endswith("raise the limit")
    # a residual short of a tolerance float32 cannot reach, with exact weights: written, said so, exit code 1
    rc = main(["bind", str(EXAMPLE / "arm.obj"), str(EXAMPLE / "arm_cage.obj"), "-o", str(out),
               "--resolution", "16", "--device", device, "--tol", "1e-9"])
    captured = capsys.readouterr()
    assert rc == 1 and out.exists() and "NOT converged" in captured.out
    assert "the solver did not reach tol 1e-09" in captured.err and "float32 accuracy limit" in captured.err
    assert ws.load_binding(out).stats.partition_of_unity_error <= 1e-6


def test_a_recovered_solve_says_so_once(tmp_path, monkeypatch):
    # the command, its smoothers' bounds forced too low (the fault the watchdog recovers from): it binds, says in its
    # table what it did, and warns once on stderr. On 2 threads each lane recovers on its own (its own smoother
    # bounds: none changes under another lane's cycles): a fault per chunk, one warning
    from warp_stokes.solver import multigrid

    monkeypatch.setattr(multigrid, "LMAX_SAFETY", 0.3)
    out = tmp_path / "arm.npz"
    for threads in (1, 2):
        proc = cli("bind", EXAMPLE / "arm.obj", EXAMPLE / "arm_cage.obj", "-o", out, "--resolution", "20", "--device",
                   "cpu", "--threads", threads)
        assert proc.returncode == 0, proc.stderr
        assert (f"converged (after {threads} fault(s) of its preconditioner, with multigrid with guaranteed smoother "
                "bounds)") in proc.stdout
        assert (f"{threads} chunk(s) on 2 threads" in proc.stdout) == (threads == 2)
        notices = [line for line in proc.stderr.splitlines() if "the solver's" in line]
        assert len(notices) == 1 and notices[0].startswith("warning: the solver's multigrid preconditioner failed after "
                                                           "0 iterations (the preconditioner is not positive definite")
        recoveries = ws.load_binding(out).stats.solver.recoveries
        assert [e["next"] for e in recoveries] == ["multigrid with guaranteed smoother bounds"] * threads


def test_bad_budget_and_resolution_fail_cleanly(tmp_path, capsys):
    args = ["bind", str(EXAMPLE / "arm.obj"), str(EXAMPLE / "arm_cage.obj"), "-o", str(tmp_path / "x.npz")]
    assert main(args + ["--memory-gb", "-1"]) == 2
    assert capsys.readouterr().err == "warp-stokes bind: error: argument --memory-gb: must be > 0, got -1\n"
    # 7e9 nodes: the dense grid alone would need ~94 GiB, refused before allocating anything
    assert main(args + ["--resolution", "2048"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "resolution 2048 has" in err[0] and "or less would fit" in err[0]


def test_console_script_is_installed(tmp_path):
    exe = shutil.which("warp-stokes")
    assert exe, "the warp-stokes command is not on PATH: is the package installed?"
    proc = subprocess.run([exe, "bind", str(tmp_path / "nope.obj"), str(EXAMPLE / "arm_cage.obj"), "-o",
                           str(tmp_path / "x.npz")], capture_output=True, text=True)
    assert proc.returncode == 2
    assert "nope.obj: no such file" in proc.stderr


def test_a_first_run_says_it_compiles_the_kernels(tmp_path, monkeypatch, capsys):
    import warp as wp

    import warp_stokes.kernel_cache as device

    assert device.kernels_compiled("cpu")  # the suite has run kernels on the CPU by now
    empty = tmp_path / "cache"
    empty.mkdir()
    monkeypatch.setattr(wp.config, "kernel_cache_dir", str(empty))
    assert not device.kernels_compiled("cpu")  # nothing compiled in this cache
    for module, _ in device._warp_modules(device.KERNEL_MODULES, ws.resolve_device("cpu")):  # every CPU object file
        (empty / f"wp_{module.name}_abc1234").mkdir()
        (empty / f"wp_{module.name}_abc1234" / f"wp_{module.name}.cpu1.o").write_text("")
    assert device.kernels_compiled("cpu")
    # harmonic coordinates also need the Laplace kernels, compiled only by a harmonic bind
    assert not device.kernels_compiled("cpu", device.KERNEL_MODULES + ("laplace",))
    # a machine that has only bound (never deformed) has what a bind needs: no notice (there was one, measured)
    for folder in empty.glob("wp_warp_stokes.kernels.deform_*"):
        for f in folder.iterdir():
            f.unlink()
        folder.rmdir()
    assert not device.kernels_compiled("cpu") and device.kernels_compiled("cpu", device.BIND_MODULES)
    device.announce_compilation("cpu")
    assert "compiling" not in capsys.readouterr().err


def test_kernels_compiled_at_once_are_the_ones_the_launches_use(tmp_path, monkeypatch):
    """compile_kernels fills an empty cache with a module's kernels, those compiled alone (the CPU's node loops)
    included, and leaves out the GPU's patch walks on a CPU: the launches after it compile nothing more."""
    import warp as wp

    import warp_stokes.kernel_cache as device
    from warp_stokes.kernels import stencil
    from warp_stokes.solver.operator import apply_operator, chebyshev_step

    cpu = ws.resolve_device("cpu")
    mask = np.zeros((12, 12, 12), bool)
    mask[5:7, 5:7, 5:7] = True
    grid = ws.grid_from_mask(mask, device="cpu")  # with the suite's cache (the voxel kernels)
    monkeypatch.setattr(wp.config, "kernel_cache_dir", str(tmp_path))
    modules = ("cg", "stencil", "stencil_cpu")
    found = device._warp_modules(modules, cpu)
    alone = [m for m, _ in found if not m.name.startswith("warp_stokes.kernels.")]
    assert len(alone) >= 4 and not device.kernels_compiled("cpu", modules)
    assert not any(k.module is m for k in stencil.CUDA_ONLY for m, _ in found)  # walks: a GPU's only
    assert {k.module for k in stencil.CUDA_ONLY} <= {m for m, _ in device._warp_modules(modules, FakeCuda())}
    for module, _ in found:  # loaded by earlier tests: as in a fresh process
        module.unload()
    device.compile_kernels("cpu", modules, workers=2)
    assert device.kernels_compiled("cpu", modules)
    compiled = sorted(p.name for p in tmp_path.iterdir())
    field = wp.zeros((grid.n_active, 2), dtype=wp.vec4f, device="cpu")
    out = wp.empty((grid.n_interior, 2), dtype=wp.vec4f, device="cpu")
    for module in alone:  # unload them: the next launches load them from the cache, or compile them afresh
        module.unload()
    apply_operator(grid, field, out, device="cpu", precise=False)
    apply_operator(grid, field, out, device="cpu")
    apply_operator(grid, field, out, device="cpu", rhs=wp.zeros_like(out), precise=False)
    chebyshev_step(grid, field, wp.zeros_like(out), wp.zeros_like(out), 0.5, 0.5, wp.zeros_like(out), grid.n_interior,
                   device="cpu")
    assert sorted(p.name for p in tmp_path.iterdir()) == compiled


class FakeCuda:
    """What kernel_cache._warp_modules reads of a CUDA device."""
    is_cpu, is_cuda = False, True


def test_the_command_says_so_before_it_compiles(tmp_path, monkeypatch, capsys):
    import warp_stokes.kernel_cache as device

    monkeypatch.setattr(device, "missing_kernels", lambda d=None, modules=(): list(modules))  # as on a fresh machine
    rc = main(["bind", str(EXAMPLE / "arm.obj"), str(EXAMPLE / "arm_cage.obj"), "-o", str(tmp_path / "a.npz"),
               "--resolution", "8", "--device", "cpu"])
    err = capsys.readouterr().err
    assert rc == 0 and "compiling the kernels for cpu (first run on this machine" in err


def test_a_compile_notice_names_the_modules_it_compiles_where_it_is_not_the_first_run(monkeypatch):
    """Where a bind's kernels are in the cache and only others are not (the Laplace kernels of a first harmonic bind),
    the notice names those and says why, instead of "first run on this machine"."""
    import io

    import warp_stokes.kernel_cache as cache

    monkeypatch.setattr(cache, "missing_kernels", lambda d=None, modules=(): [m for m in modules if m == "laplace"])
    monkeypatch.setattr(cache, "compile_kernels", lambda d, modules: None)
    said = io.StringIO()
    cache.announce_compilation("cpu", harmonic=True, stream=said)
    assert "not yet in Warp's cache on this machine: laplace (harmonic coordinates)" in said.getvalue()
    assert "first run" not in said.getvalue()


def test_deform_on_a_cpu_imports_none_of_the_binds_kernels(arm_npz, tmp_path):
    """A deform on the CPU (BLAS) loads the binding and writes the mesh without importing the grid's, the solver's or
    the boundary data's kernel modules, nor the bind's stages: its start-up is the binding's reading and numpy's."""
    import subprocess
    import sys

    np.save(tmp_path / "pose.npy", ws.load_binding(arm_npz, device="cpu").cage_vertices * 1.1)
    script = ("import sys\nfrom warp_stokes.cli import main\n"
              f"rc = main(['deform', {str(arm_npz)!r}, {str(tmp_path / 'pose.npy')!r}, '-o', "
              f"{str(tmp_path / 'out.obj')!r}, '--device', 'cpu'])\n"
              "print('modules', rc, sorted(m for m in sys.modules if m.startswith('warp_stokes.')))")
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    _, rc, modules = proc.stdout.strip().splitlines()[-1].split(" ", 2)
    assert rc == "0" and (tmp_path / "out.obj").is_file(), proc.stderr
    heavy = ["kernels.stencil", "kernels.voxel", "kernels.multigrid", "kernels.cg", "binding.pipeline",
             "binding.skin", "solver", "geometry.grid", "geometry.cage_making"]
    assert not [m for m in heavy if f"'warp_stokes.{m}" in modules], modules
