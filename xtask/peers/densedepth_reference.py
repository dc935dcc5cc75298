"""The reference DenseDepth in PyTorch, under its own `state_dict` names: Encoder (torchvision
DenseNet as `encoder.original_model`, its features' outputs all kept as skips) and Decoder
(conv2, up1..up4 with convA/convB, conv3). Shared by the peers in this folder. `channels` and
`full_resolution` give this project's variants (`model::torch::differences_from_reference`): conv0
reading that many channels, and a fifth up block (`up5`, skip = the input) before conv3.
"""
import torch, torch.nn as nn, torch.nn.functional as F
from torchvision.models.densenet import DenseNet


class UpSample(nn.Module):
    def __init__(self, skip_input, output_features):
        super().__init__()
        self.convA = nn.Conv2d(skip_input, output_features, 3, 1, 1)
        self.convB = nn.Conv2d(output_features, output_features, 3, 1, 1)

    def forward(self, x, concat_with):
        up = F.interpolate(x, size=concat_with.shape[2:], mode="bilinear", align_corners=True)
        return F.leaky_relu(self.convB(F.leaky_relu(self.convA(torch.cat([up, concat_with], 1)), 0.2)), 0.2)


class Encoder(nn.Module):
    def __init__(self, growth, blocks, init, bn_size, channels=3):
        super().__init__()
        self.original_model = DenseNet(growth_rate=growth, block_config=tuple(blocks), num_init_features=init,
                                       bn_size=bn_size)
        if channels != 3:
            self.original_model.features.conv0 = nn.Conv2d(channels, init, 7, 2, 3, bias=False)

    def forward(self, x):
        features = [x]
        for layer in self.original_model.features:
            features.append(layer(features[-1]))
        return features


class Decoder(nn.Module):
    def __init__(self, growth, blocks, init, width=0.5, full_input=None):
        super().__init__()
        c = init; skips = [c, c]
        for i, n in enumerate(blocks):
            c += n * growth
            if i < 3:
                c //= 2; skips.append(c)
        n = int(c * width)
        self.conv2 = nn.Conv2d(c, n, 1)
        self.up1 = UpSample(n + skips[3], n // 2); self.up2 = UpSample(n // 2 + skips[2], n // 4)
        self.up3 = UpSample(n // 4 + skips[1], n // 8); self.up4 = UpSample(n // 8 + skips[0], n // 16)
        # At the input's resolution: the input itself is the last skip.
        self.up5 = UpSample(n // 16 + full_input, n // 16) if full_input else None
        self.conv3 = nn.Conv2d(n // 16, 1, 3, 1, 1)

    def forward(self, f):
        # Skips: relu0, pool0, transition1, transition2; the bottleneck is relu(norm5).
        x = self.conv2(F.relu(f[12]))
        x = self.up1(x, f[8]); x = self.up2(x, f[6]); x = self.up3(x, f[4]); x = self.up4(x, f[3])
        if self.up5 is not None:
            x = self.up5(x, f[0])
        return self.conv3(x)


class Model(nn.Module):
    def __init__(self, growth, blocks, init, bn_size, width=0.5, channels=3, full_resolution=False):
        super().__init__()
        self.encoder = Encoder(growth, blocks, init, bn_size, channels)
        self.decoder = Decoder(growth, blocks, init, width, channels if full_resolution else None)

    def forward(self, x):
        return self.decoder(self.encoder(x))
