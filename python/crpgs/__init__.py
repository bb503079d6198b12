"""crpgs: compress 3D Gaussian Splatting scenes with CRP-GS (and HAC) from Python.

The C++ SDK's pipeline (docs/python.md): open a model (a .crpgs bitstream, a `crpgs decode`
directory or a training run) and render any camera into a torch.Tensor; train a config with a
progress callback; encode a run's bitstream at other rates; inspect a bitstream; read a run's
metrics.json; BD-rate and BD-PSNR. SDK errors raise crpgs.Error with the SDK's message.

    import crpgs
    model = crpgs.open("runs/fern/scene.crpgs")
    camera = model.cameras("test")[0]
    image = model.render(camera)          # [H, W, 3] float32 in [0, 1]
    print(model.evaluate()["psnr"])
"""
import json as _json
import os as _os
import sys as _sys

# Idle OpenMP and OpenBLAS threads sleep instead of spinning (what the crpgs CLI sets for
# itself): on a loaded machine spinning workers slow training several times. Read when the
# libraries load, so only when torch is not imported yet; a variable already set is kept.
if "torch" not in _sys.modules:
    _os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    _os.environ.setdefault("OPENBLAS_THREAD_TIMEOUT", "4")

import torch  # noqa: E402,F401  (loads libtorch before the extension that links it)

from . import _crpgs
from ._crpgs import Camera, Error, Model, Scene, __version__, bd_psnr, bd_rate, commit  # noqa: F401

__all__ = [
    "Camera", "Error", "Model", "Scene", "bd_psnr", "bd_rate", "encode", "info", "open",
    "open_dataset", "read_metrics", "train", "__version__",
]


# An installed package finds the installed plugins beside it (PREFIX/lib/crpgs/plugins, three
# folders up from PREFIX/lib/pythonX.Y/dist-packages/crpgs); a build tree's extension knows its
# own plugin folder.
_INSTALLED_PLUGINS = _os.path.normpath(
    _os.path.join(_os.path.dirname(__file__), "..", "..", "..", "crpgs", "plugins"))


def _paths(ps):
    dirs = [str(p) for p in ps]
    if _os.path.isdir(_INSTALLED_PLUGINS):
        dirs.append(_INSTALLED_PLUGINS)
    return dirs


def train(config, out_dir, sets=(), progress=None, resume=False, method="", plugin_dirs=()):
    """Trains `config` (a YAML file; "key=value" overrides in `sets`) into out_dir: checkpoints,
    the resolved config.yaml and, on the rate path, the bitstream scene.crpgs, written and
    checked (decoded and evaluated). progress(report) is called every iteration with a dict
    (iteration, total, loss, test_psnr, anchors, gaussians, iterations_per_second); an exception
    it raises, or Ctrl-C, stops training with a checkpoint (resume=True continues) and is raised.
    out_dir ends as `crpgs train -o out_dir` leaves it (metrics.json too; `method` names the run
    there, default the config file's name). Returns {iterations, seconds, checkpoint, metrics
    (metrics.json as a dict)[, bitstream: {path, bytes, psnr, ...}]}."""
    out = _crpgs.train(str(config), str(out_dir), list(sets), progress, resume, method,
                       _paths(plugin_dirs))
    out["metrics"] = _json.loads(out.pop("metrics_json"))
    return out


def encode(run_dir, out, rate_scale=1.0, target_size=None, plugin_dirs=()):
    """Writes a finished run's bitstream to `out` with its quantisation steps scaled by
    rate_scale (> 1: smaller, < 1: larger), or the best file at or under target_size bytes
    (crpgs.Error naming the smallest size the model reaches when it is below that), then decodes
    and evaluates it. The result has the rate_scale used."""
    return _crpgs.encode(str(run_dir), str(out), float(rate_scale), int(target_size or 0),
                         _paths(plugin_dirs))


def info(path, plugin_dirs=()):
    """A bitstream's size, anchors and sections (id, component, bytes, category)."""
    return _crpgs.info(str(path), _paths(plugin_dirs))


def open(source, sets=(), threads=0, plugin_dirs=()):  # noqa: A001  (crpgs.open, like io.open)
    """Opens a .crpgs file, a `crpgs decode` directory or a training run directory.

    sets: "key=value" overrides of the dataset/rasterizer (e.g. "dataset.path=DIR");
    threads: CPU threads (0 keeps the config's)."""
    return Model(str(source), list(sets), threads, _paths(plugin_dirs))


def open_dataset(config, sets=(), plugin_dirs=()):
    """The dataset a config names (with "key=value" overrides): a Scene with cameras(split),
    image(split, i), name and warnings, without training or opening a model."""
    return Scene(str(config), list(sets), _paths(plugin_dirs))


def read_metrics(path):
    """A run's metrics.json (or the file itself) as a dict, validated by the SDK's reader."""
    path = str(path)
    if _os.path.isdir(path):
        path = _os.path.join(path, "metrics.json")
    return _json.loads(_crpgs.metrics_json(path))
