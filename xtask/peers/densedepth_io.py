"""Writes IO.safetensors for `check_import`: a random input of the size asked for and the
reference DenseDepth's eval-mode output on it, from a state_dict under the reference's names.

usage: python densedepth_io.py WEIGHTS.pth HEIGHT WIDTH OUT.safetensors
           [--growth 10 --blocks 2,3,4,3 --init 24 --bn-size 2 --width 0.5 --seed 0]
(defaults: the tiny fixture's sizes, ../shared/fixtures/densedepth_tiny.json; DenseNet-161 is
--growth 48 --blocks 6,12,36,24 --init 96 --bn-size 4)
"""
import argparse

import torch
from safetensors.torch import save_file

from densedepth_reference import Model


def main():
    a = argparse.ArgumentParser()
    a.add_argument("weights"); a.add_argument("height", type=int); a.add_argument("width", type=int)
    a.add_argument("out")
    a.add_argument("--growth", type=int, default=10); a.add_argument("--blocks", default="2,3,4,3")
    a.add_argument("--init", type=int, default=24); a.add_argument("--bn-size", type=int, default=2)
    a.add_argument("--width", dest="decoder_width", type=float, default=0.5)
    a.add_argument("--seed", type=int, default=0)
    args = a.parse_args()
    blocks = tuple(int(b) for b in args.blocks.split(","))
    model = Model(args.growth, blocks, args.init, args.bn_size, args.decoder_width)
    model.load_state_dict(torch.load(args.weights, map_location="cpu"), strict=True)
    model.eval()
    torch.manual_seed(args.seed)
    x = torch.rand(1, 3, args.height, args.width)
    with torch.no_grad():
        y = model(x)
    save_file({"input": x.contiguous(), "output": y.contiguous()}, args.out)
    print(f"{args.out}: input {list(x.shape)}, output {list(y.shape)}")


if __name__ == "__main__":
    main()
