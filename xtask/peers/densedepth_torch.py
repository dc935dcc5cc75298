"""Peer for `cargo xtask bench model`: the same DenseDepth architecture in PyTorch (the reference
model, `densedepth_reference.py`), on the CPU or
(--device cuda) the first CUDA GPU. Not part of CI. Needs: pip install torch torchvision.

Prints one line per batch size: batch=B forward_ms=X forward_q1_ms forward_q3_ms train_ms=Y train_q1_ms
train_q3_ms device=D (medians and quartiles, numpy's rule; the train step is forward, the DenseDepth loss,
backward and an Adam step, as in the Burn benchmark). --channels and --full-resolution build the
quickstart's network (conv0 reading that many channels; a fifth up block whose skip is the input).
"""
import argparse, statistics, time
import torch, torch.nn as nn, torch.nn.functional as F
from densedepth_reference import Model

ap = argparse.ArgumentParser()
ap.add_argument("--growth", type=int); ap.add_argument("--blocks"); ap.add_argument("--init", type=int)
ap.add_argument("--bn-size", type=int); ap.add_argument("--height", type=int); ap.add_argument("--width", type=int)
ap.add_argument("--batches"); ap.add_argument("--reps", type=int, default=3); ap.add_argument("--threads", type=int)
ap.add_argument("--device", default="cpu"); ap.add_argument("--channels", type=int, default=3)
ap.add_argument("--full-resolution", action="store_true")
a = ap.parse_args()
# A GPU run of Burn is compared with PyTorch on CUDA when there is CUDA, else on the CPU.
dev = torch.device(a.device if a.device == "cpu" or torch.cuda.is_available() else "cpu")
# cuDNN picks its fastest convolution per shape, as Burn's GPU backends autotune theirs.
torch.backends.cudnn.benchmark = True
torch.set_num_threads(a.threads)
blocks = tuple(int(x) for x in a.blocks.split(","))

def gauss(ws=11, sigma=1.5):
    t = torch.arange(ws, dtype=torch.float32) - ws // 2
    g = torch.exp(-t ** 2 / (2 * sigma ** 2)); g = g / g.sum()
    return (g[:, None] * g[None, :])[None, None]

def loss_fn(p, t, L=990.0):
    w = gauss().to(p.device); p, t = p / L, t / L
    mp, mt = F.conv2d(p, w), F.conv2d(t, w)
    spp = F.conv2d(p * p, w) - mp ** 2; stt = F.conv2d(t * t, w) - mt ** 2; spt = F.conv2d(p * t, w) - mp * mt
    C1, C2 = 0.01 ** 2, 0.03 ** 2
    ssim = (((2 * mp * mt + C1) * (2 * spt + C2)) / ((mp ** 2 + mt ** 2 + C1) * (spp + stt + C2))).mean()
    p, t = p * L, t * L
    dy = lambda x: x[:, :, 1:] - x[:, :, :-1]; dx = lambda x: x[:, :, :, 1:] - x[:, :, :, :-1]
    n = p.numel()
    edge = ((dy(p) - dy(t)).abs().sum() + (dx(p) - dx(t)).abs().sum()) / n
    return torch.clamp((1 - ssim) / 2, 0, 1) + edge + 0.1 * (p - t).abs().mean()

def sync():
    if dev.type == "cuda": torch.cuda.synchronize()

def timed(f, reps):
    """(q1, median, q3) of `reps` timed runs after a warm-up (ms)."""
    f(); sync(); ts = []
    for _ in range(reps):
        t = time.perf_counter(); f(); sync(); ts.append((time.perf_counter() - t) * 1e3)
    return statistics.quantiles(ts, n=4, method="inclusive") if len(ts) > 1 else ts * 3

for b in (int(x) for x in a.batches.split(",")):
    m = Model(a.growth, blocks, a.init, a.bn_size, channels=a.channels, full_resolution=a.full_resolution).to(dev)
    x = torch.rand(b, a.channels, a.height, a.width, device=dev)
    m.eval()
    with torch.no_grad():
        fwd = timed(lambda: m(x), a.reps)
    m.train()
    opt = torch.optim.Adam(m.parameters(), lr=1e-4)
    oh, ow = (a.height, a.width) if a.full_resolution else ((a.height + 1) // 2, (a.width + 1) // 2)
    target = 10 + 990 * torch.rand(b, 1, oh, ow, device=dev)
    def step():
        opt.zero_grad(); loss_fn(m(x), target).backward(); opt.step()
    tr = timed(step, a.reps)
    print(f"batch={b} forward_ms={fwd[1]:.3f} forward_q1_ms={fwd[0]:.3f} forward_q3_ms={fwd[2]:.3f} "
          f"train_ms={tr[1]:.3f} train_q1_ms={tr[0]:.3f} train_q3_ms={tr[2]:.3f} device={dev.type}", flush=True)
