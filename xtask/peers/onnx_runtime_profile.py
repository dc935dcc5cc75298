"""Where ONNX Runtime's forward time goes on a DenseDepth graph: encoder against decoder, by
operator and by node, from ONNX Runtime's own profiler (CPU, the thread count given). Not part of
CI. Needs: pip install onnxruntime numpy (and torch, torchvision for --export-reference).

usage: python onnx_runtime_profile.py MODEL.onnx --height 480 --width 640 --threads 2 [--channels 6]
       [--export-reference]   # first write MODEL.onnx: the reference DenseDepth-161 by torch.onnx
Nodes are split by name: those with "decoder" in it (our export's `decoder.up1.conv_a`, PyTorch's
`/decoder/up1/convA/Conv`) against the rest.
"""
import argparse, collections, json, os, statistics, tempfile, time

import numpy as np
import onnxruntime as ort

ap = argparse.ArgumentParser()
ap.add_argument("model"); ap.add_argument("--height", type=int, default=480); ap.add_argument("--width", type=int, default=640)
ap.add_argument("--threads", type=int, default=2); ap.add_argument("--reps", type=int, default=4)
ap.add_argument("--channels", type=int, default=3)
ap.add_argument("--export-reference", action="store_true")
a = ap.parse_args()
if a.export_reference:
    import torch
    from densedepth_reference import Model
    net = Model(48, (6, 12, 36, 24), 96, 4, 0.5).eval()
    torch.onnx.export(net, torch.rand(1, 3, a.height, a.width), a.model, opset_version=17, input_names=["x"], dynamo=False)

options = ort.SessionOptions()
options.intra_op_num_threads = a.threads
options.inter_op_num_threads = 1
options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
# The profiler's JSON goes to the temporary folder and is removed once read.
options.profile_file_prefix = os.path.join(tempfile.gettempdir(), "densetact_ort_profile")
x = np.random.default_rng(0).random((1, a.channels, a.height, a.width), dtype=np.float32)


def session(profile):
    options.enable_profiling = profile
    s = ort.InferenceSession(a.model, options, providers=["CPUExecutionProvider"])
    return s, s.get_inputs()[0].name


s, name = session(False)
s.run(None, {name: x})
times = []
for _ in range(a.reps):
    t = time.perf_counter(); s.run(None, {name: x}); times.append((time.perf_counter() - t) * 1e3)
print(f"forward ms, median of {a.reps} without the profiler: {statistics.median(times):.3f}")

s, name = session(True)
for _ in range(a.reps):
    s.run(None, {name: x})
profile = s.end_profiling()
with open(profile) as f:
    events = json.load(f)
os.remove(profile)
nodes = [e for e in events if e.get("cat") == "Node" and e["name"].endswith("_kernel_time")]
part, by_op, by_node, by_stage = collections.Counter(), collections.Counter(), collections.Counter(), collections.Counter()
for e in nodes:
    node = e["name"][: -len("_kernel_time")]
    side = "decoder" if "decoder" in node else "encoder"
    ms = e["dur"] / 1e3 / a.reps
    part[side] += ms
    by_op[f"{side} {e['args'].get('op_name', '?')}"] += ms
    by_node[node] += ms
    by_stage[".".join(node.split(".")[:2])] += ms
print("kernel ms per forward (profiled): " + ", ".join(f"{k} {v:.3f}" for k, v in sorted(part.items())))
for k, v in by_op.most_common(8):
    print(f"{v:8.3f} ms  {k}")
for k, v in by_node.most_common(12):
    print(f"{v:8.3f} ms  {k}")
print("by stage (the node names' first two parts):")
for k, v in sorted(by_stage.items()):
    print(f"{v:8.3f} ms  {k}")
