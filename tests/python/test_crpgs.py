"""The crpgs Python package against the CLI: renders equal pixel for pixel, a bitstream written
from Python decodes in the CLI, errors carry the SDK's message, the progress callback is called
and an exception raised in it stops training with a checkpoint to resume from.

Run by ctest (tests/CMakeLists.txt: python.pytest) with PYTHONPATH=BUILD/python and CRPGS_EXE.
"""
import os
import shutil
import subprocess
from pathlib import Path

import pytest
import torch
from PIL import Image

import crpgs

CRPGS = os.environ["CRPGS_EXE"]

# tests/data/tiny_rate.yaml: a small synthetic scene through every phase in 12 iterations (as the
# C++ codec tests train it).
CONFIG = (Path(__file__).resolve().parents[1] / "data" / "tiny_rate.yaml").read_text()


def cli(*args):
    r = subprocess.run([CRPGS, *map(str, args)], capture_output=True, text=True)
    return r.returncode, r.stdout + r.stderr


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """A run trained from Python: (directory, what train returned, progress reports)."""
    d = tmp_path_factory.mktemp("py")
    (d / "tiny.yaml").write_text(CONFIG)
    reports = []
    out = crpgs.train(d / "tiny.yaml", d / "run", progress=reports.append)
    return d, out, reports


def test_train_reports_progress_and_writes_a_checked_bitstream(trained):
    d, out, reports = trained
    assert out["iterations"] == 12
    assert [r["iteration"] for r in reports] == list(range(1, 13))
    assert all(r["total"] == 12 and r["loss"] > 0 for r in reports)
    b = out["bitstream"]
    assert b["path"] == str(d / "run" / "scene.crpgs")
    assert b["bytes"] == os.path.getsize(b["path"]) > 0
    assert b["psnr"] > 10
    # metrics.json as the CLI writes it, and the run directory a `crpgs train` run would be.
    m = crpgs.read_metrics(d / "run")
    assert m == out["metrics"]
    assert m["size_bytes"] == b["bytes"] and m["method"] == "tiny"
    assert abs(m["psnr_mean"] - b["psnr"]) < 1e-9
    assert (d / "run" / "config.yaml").exists() and not (d / "run" / ".running").exists()


def test_a_bitstream_written_from_python_decodes_in_the_cli(trained):
    d, out, _ = trained
    rc, log = cli("eval", d / "run" / "scene.crpgs")
    assert rc == 0, log
    mean = [line.split() for line in log.splitlines() if line.startswith("mean")]
    assert mean and abs(float(mean[0][1]) - out["bitstream"]["psnr"]) < 5e-4, log
    assert crpgs.info(d / "run" / "scene.crpgs")["bytes"] == out["bitstream"]["bytes"]


def test_a_render_from_python_equals_the_clis_pixel_for_pixel(trained):
    d, _, _ = trained
    rc, log = cli("render", d / "run" / "scene.crpgs", "-o", d / "png", "--views", "test",
                  "--threads", 1)
    assert rc == 0, log
    model = crpgs.open(d / "run" / "scene.crpgs", threads=1)
    assert model.kind == "bitstream"
    cameras = model.cameras("test")
    assert cameras, "the synthetic scene has test views"
    for i, camera in enumerate(cameras):
        image = model.render(camera)
        assert image.shape == (camera.height, camera.width, 3) and image.dtype == torch.float32
        ours = (image.clamp(0, 1) * 255).round().to(torch.uint8)  # as the CLI writes PNGs
        png = Image.open(d / "png" / f"test_{i:05d}.png").convert("RGB")
        cli_png = torch.frombuffer(bytearray(png.tobytes()), dtype=torch.uint8).view(
            png.height, png.width, 3)
        assert torch.equal(ours, cli_png), f"test view {i}"
    # The dataset opened from the config alone has the same views and photos.
    scene = crpgs.open_dataset(d / "tiny.yaml")
    assert len(scene.cameras("test")) == len(cameras) and len(scene.cameras("train")) > 0
    assert torch.equal(scene.image("test", 0), model.image("test", 0))
    assert scene.cameras("test")[0].name == cameras[0].name
    with pytest.raises(ValueError, match="split"):
        scene.cameras("val")
    with pytest.raises(IndexError):
        scene.image("test", len(cameras))
    # A camera built in Python from the same numbers renders the same image.
    c = cameras[0]
    again = crpgs.Camera(c.width, c.height, c.fx, c.fy, c.cx, c.cy, c.world_to_camera, "copy")
    assert torch.equal(model.render(again), model.render(c))


def test_python_and_cli_agree_on_the_run_and_on_encoding_at_another_rate(trained):
    d, out, _ = trained
    run = crpgs.open(d / "run", threads=1)
    assert run.kind == "run"
    ev = run.evaluate()
    assert abs(ev["psnr"] - out["bitstream"]["psnr"]) < 1e-6  # the run renders as its file
    half = crpgs.encode(d / "run", d / "half.crpgs", rate_scale=4.0)
    assert half["bytes"] < out["bitstream"]["bytes"]
    rc, log = cli("info", d / "half.crpgs")
    assert rc == 0, log
    target = (half["bytes"] + out["bitstream"]["bytes"]) // 2
    fit = crpgs.encode(d / "run", d / "fit.crpgs", target_size=target)
    assert 0.97 * target <= fit["bytes"] <= target and 1 < fit["rate_scale"] < 4
    with pytest.raises(crpgs.Error, match="below what this model reaches"):
        crpgs.encode(d / "run", d / "tiny.crpgs", target_size=100)


def test_export_from_python_writes_the_clis_ply_byte_for_byte(trained):
    d, _, _ = trained
    rc, log = cli("export", d / "run" / "scene.crpgs", "-o", d / "cli.ply", "--refine", 3,
                  "--threads", 1)
    assert rc == 0, log
    model = crpgs.open(d / "run" / "scene.crpgs", threads=1)
    out = model.export_ply(d / "py.ply", refine=3)
    assert (d / "py.ply").read_bytes() == (d / "cli.ply").read_bytes()
    assert out["gaussians"] > 0 and out["bytes"] == os.path.getsize(d / "py.ply")
    assert out["refine_iterations"] == 3
    mean = [line.split() for line in log.splitlines() if line.startswith("mean")][0]
    assert abs(out["anchor_psnr"] - float(mean[1])) < 5e-4 and abs(out["psnr"] - float(mean[2])) < 5e-4
    with pytest.raises(ValueError, match="sh_degree"):
        model.export_ply(d / "bad.ply", sh_degree=4)


def test_errors_raise_crpgs_error_with_the_sdks_message(tmp_path):
    with pytest.raises(crpgs.Error, match="no such file or directory"):
        crpgs.open(tmp_path / "missing.crpgs")
    bad = tmp_path / "corrupt.crpgs"
    bad.write_bytes(b"CRPG" + bytes(60))
    with pytest.raises(crpgs.Error, match="corrupt.crpgs"):
        crpgs.open(bad)
    with pytest.raises(crpgs.Error, match="corrupt.crpgs"):
        crpgs.info(bad)
    (tmp_path / "bad.yaml").write_text("train: {iterations: many}\n")
    with pytest.raises(crpgs.Error, match="iterations"):
        crpgs.train(tmp_path / "bad.yaml", tmp_path / "run")
    with pytest.raises(crpgs.Error):
        crpgs.read_metrics(tmp_path)


def test_an_exception_in_the_callback_stops_training_with_a_checkpoint(tmp_path):
    (tmp_path / "tiny.yaml").write_text(CONFIG)

    def stop_at_5(report):
        if report["iteration"] == 5:
            raise KeyboardInterrupt("enough")

    with pytest.raises(KeyboardInterrupt, match="enough"):
        crpgs.train(tmp_path / "tiny.yaml", tmp_path / "run", progress=stop_at_5)
    assert (tmp_path / "run" / "checkpoint.pt").exists()
    assert not (tmp_path / "run" / "scene.crpgs").exists()
    seen = []
    out = crpgs.train(tmp_path / "tiny.yaml", tmp_path / "run", resume=True,
                      progress=lambda r: seen.append(r["iteration"]))
    assert out["iterations"] == 12
    assert seen[0] > 5 and seen[-1] == 12  # continued, not restarted
    assert os.path.getsize(out["bitstream"]["path"]) == out["bitstream"]["bytes"]


def test_ctrl_c_stops_training_with_a_checkpoint(tmp_path):
    """A real SIGINT (as Ctrl-C sends) during crpgs.train: KeyboardInterrupt after a checkpoint."""
    (tmp_path / "tiny.yaml").write_text(CONFIG)
    script = (
        "import os, signal, crpgs\n"
        "def progress(r):\n"
        "    if r['iteration'] == 3: os.kill(os.getpid(), signal.SIGINT)\n"
        "try:\n"
        f"    crpgs.train({str(tmp_path / 'tiny.yaml')!r}, {str(tmp_path / 'run')!r}, progress=progress)\n"
        "except KeyboardInterrupt:\n"
        "    print('interrupted')\n")
    r = subprocess.run([os.sys.executable, "-c", script], capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0 and "interrupted" in r.stdout, r.stdout + r.stderr
    assert (tmp_path / "run" / "checkpoint.pt").exists()
    assert not (tmp_path / "run" / "scene.crpgs").exists()


def test_bd_figures_and_metrics(trained):
    anchor = [(1000, 30.0), (2000, 31.0), (4000, 32.0)]
    test = [(s * 0.8, p) for s, p in anchor]
    assert crpgs.bd_rate(anchor, test) == pytest.approx(-20.0, abs=1e-6)
    assert crpgs.bd_psnr(anchor, anchor) == pytest.approx(0.0, abs=1e-9)
    assert crpgs.bd_rate(anchor, [(1e9, 60.0), (2e9, 61.0)]) is None  # no common interval
    d, _, _ = trained
    shutil.rmtree(d / "cli", ignore_errors=True)
    rc, log = cli("train", "-c", d / "tiny.yaml", "-o", d / "cli")
    assert rc == 0, log
    m = crpgs.read_metrics(d / "cli")
    assert m["size_bytes"] == os.path.getsize(d / "cli" / "scene.crpgs")
    assert m["dataset"] and len(m["views"]) > 0
