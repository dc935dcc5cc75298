"""Makes the import test cases in this folder (run once; needs torch, torchvision, safetensors).

usage: python make_import_cases.py SHARED_FIXTURES_DIR

- densedepth_tiny_legacy.pth: the shared fixture's model (same seed) with torchvision's legacy
  keys (`denselayer1.norm.1.weight`); the shared densedepth_tiny_io.safetensors applies to it.
- densenet_micro.pth + densenet_micro_io.safetensors: a bare torchvision DenseNet checkpoint
  (legacy keys, classifier included), as users download for ImageNet initialisation, with the
  eval-mode output of `features` (norm5, before its ReLU) for a random input.
- micro_missing.pth, micro_misshaped.pth, micro_extra.pth, not_densenet.pth: broken files.
"""
import os, re, subprocess, sys, tempfile
import torch
from torchvision.models.densenet import DenseNet
from safetensors.torch import save_file

here = os.path.dirname(os.path.abspath(__file__))
shared = sys.argv[1]
with tempfile.TemporaryDirectory() as tmp:
    subprocess.run([sys.executable, os.path.join(shared, "make_fixtures.py"), tmp, "--legacy-keys"], check=True)
    os.replace(os.path.join(tmp, "densedepth_tiny.pth"), os.path.join(here, "densedepth_tiny_legacy.pth"))

torch.manual_seed(3)
net = DenseNet(growth_rate=4, block_config=(1, 2, 1, 1), num_init_features=8, bn_size=2, num_classes=5)
with torch.no_grad():
    for m in net.modules():
        if isinstance(m, torch.nn.BatchNorm2d):
            m.running_mean.uniform_(-0.2, 0.2); m.running_var.uniform_(0.5, 1.5)
            m.weight.uniform_(0.8, 1.2); m.bias.uniform_(-0.1, 0.1)
net.eval()
x = torch.rand(1, 3, 64, 64)
with torch.no_grad():
    y = net.features(x)
pat = re.compile(r"(.*denselayer\d+\.(?:norm|relu|conv))((?:[12])\.(?:weight|bias|running_mean|running_var|num_batches_tracked))$")
sd = {pat.sub(lambda mm: mm.group(1) + "." + mm.group(2), k): v for k, v in net.state_dict().items()}
torch.save(sd, os.path.join(here, "densenet_micro.pth"))
save_file({"input": x.contiguous(), "norm5": y.contiguous()}, os.path.join(here, "densenet_micro_io.safetensors"))

broken = dict(sd); del broken["features.denseblock2.denselayer2.norm.1.weight"]
torch.save(broken, os.path.join(here, "micro_missing.pth"))
broken = dict(sd); broken["features.transition1.conv.weight"] = torch.zeros(3, 3, 1, 1)
torch.save(broken, os.path.join(here, "micro_misshaped.pth"))
broken = dict(sd); broken["features.denseblock1.extra_gate.weight"] = torch.zeros(4)
torch.save(broken, os.path.join(here, "micro_extra.pth"))
torch.save({"fc.weight": torch.zeros(2, 2)}, os.path.join(here, "not_densenet.pth"))
print("wrote", here)
