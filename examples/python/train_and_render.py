"""Train CRP-GS on the embedded synthetic scene for a few hundred iterations, encode it, open
the bitstream, render a test view into a PNG and print its PSNR (docs/python.md).

    PYTHONPATH=build/python /usr/bin/python3 examples/python/train_and_render.py [OUT_DIR]
"""
import os
import sys

import torch
from PIL import Image

import crpgs

root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
out = sys.argv[1] if len(sys.argv) > 1 else "runs/python_example"

# configs/crpgs.yaml (the full method) on the embedded scene, its phases at 1/100 of the
# paper's 40k-iteration schedule: 400 iterations.
result = crpgs.train(
    os.path.join(root, "configs", "crpgs.yaml"), os.path.join(out, "run"),
    sets=["dataset.format=synthetic", "train.schedule=fast", "train.fast_factor=0.01",
          "train.eval_interval=0"],
    progress=lambda p: print(f"\rtrain {p['iteration']}/{p['total']}  loss {p['loss']:.4f}",
                             end="", flush=True))
print()
bitstream = result["bitstream"]
print(f"trained {result['iterations']} iterations in {result['seconds']:.1f} s; "
      f"{bitstream['path']}: {bitstream['bytes']} bytes, {bitstream['psnr']:.3f} dB decoded")

model = crpgs.open(bitstream["path"])  # decodes the file
camera = model.cameras("test")[0]
image = model.render(camera)  # [H, W, 3] float32 in [0, 1]
truth = model.image("test", 0)
psnr = -10 * torch.log10(((image.clamp(0, 1) - truth) ** 2).mean())
png = os.path.join(out, "test_view.png")
pixels = (image.clamp(0, 1) * 255).round().to(torch.uint8)
Image.frombytes("RGB", (camera.width, camera.height), bytes(pixels.flatten().tolist())).save(png)
print(f"{png}: {camera.width}x{camera.height}, PSNR {psnr.item():.2f} dB against the photo "
      f"(float render; {model.evaluate()['psnr']:.3f} dB over all test views, 8-bit)")
