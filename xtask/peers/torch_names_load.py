"""Checks a bundle exported with `--torch-names` in PyTorch: builds the reference DenseDepth
(`densedepth_reference.py`) for the bundle's DenseNet, loads BUNDLE/weights.safetensors with
strict=True, and with --io compares its eval-mode output on the file's `input` with `output`.
Not part of CI. Needs: pip install torch torchvision safetensors.

    python3 xtask/peers/torch_names_load.py BUNDLE [--io IO.safetensors]

Prints `strict load: ok` and, with --io, `max_abs_err=X max_rel_err=Y`; exits non-zero above
1e-4 relative.
"""
import argparse, json, sys
import torch
from safetensors.torch import load_file
from densedepth_reference import Model

ap = argparse.ArgumentParser()
ap.add_argument("bundle"); ap.add_argument("--io")
a = ap.parse_args()
cfg = json.load(open(f"{a.bundle}/bundle.json"))["model"]
enc = cfg["encoder"]
if cfg.get("input", "rgb") != "rgb" or cfg.get("full_resolution", False):
    sys.exit("the bundle's model is not the reference architecture (RGB input, half-resolution output)")


model = Model(enc["growth_rate"], enc["block_config"], enc["num_init_features"], enc["bn_size"],
              cfg.get("decoder_width", 0.5))
model.load_state_dict(load_file(f"{a.bundle}/weights.safetensors"), strict=True)
model.eval()
print("strict load: ok")
if a.io:
    io = load_file(a.io)
    with torch.no_grad():
        out = model(io["input"])
    want = io["output"]
    abs_err = (out - want).abs().max().item()
    rel = abs_err / max(want.abs().max().item(), 1e-12)
    print(f"max_abs_err={abs_err:.3e} max_rel_err={rel:.3e}")
    sys.exit(0 if rel <= 1e-4 else 1)
