"""Peer for `cargo xtask bench model`: ONNX Runtime on the CPU running the model exported by
`model::onnx::export` (the same folded network Burn times), with the same thread count. Not part
of CI. Needs: pip install onnxruntime numpy.

Prints `ready version=V`, then times one forward for each batch size read from standard input,
one per line (the first of each size after a warm-up), printing forward_ms=X cpu_ms=Y (Y: the
process's CPU time since the previous forward ended, the wait for the request included, where
ONNX Runtime's workers spin by default; `--no-spin` turns that off): the Rust side
(`xtask/src/ort_peer.rs`) alternates these runs with its own, so that both see the same machine.
A line `depth B PATH` asks for the depth output of the images in PATH instead (see below).
"""
import argparse, sys, time
import numpy as np
import onnxruntime as ort

ap = argparse.ArgumentParser()
ap.add_argument("--model"); ap.add_argument("--channels", type=int, default=3)
ap.add_argument("--height", type=int); ap.add_argument("--width", type=int)
ap.add_argument("--threads", type=int)
ap.add_argument("--no-spin", action="store_true")
a = ap.parse_args()
options = ort.SessionOptions()
options.intra_op_num_threads = a.threads
if a.no_spin:
    options.add_session_config_entry("session.intra_op.allow_spinning", "0")
options.inter_op_num_threads = 1
options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
session = ort.InferenceSession(a.model, options, providers=["CPUExecutionProvider"])
name = session.get_inputs()[0].name
inputs = {}
last_cpu = time.process_time()
print(f"ready version={ort.__version__}", flush=True)
for line in sys.stdin:
    if line.startswith("depth "):
        # `depth B PATH`: the depth output for the B images in PATH (float32, little-endian,
        # [B, channels, height, width]), written to PATH.out, for the bench's error figure.
        _, b, path = line.rstrip("\n").split(" ", 2)
        x = np.fromfile(path, dtype="<f4").reshape(int(b), a.channels, a.height, a.width)
        session.run(["depth"], {name: x})[0].astype("<f4").tofile(path + ".out")
        print("depth written", flush=True)
        continue
    b = int(line)
    if b not in inputs:
        inputs[b] = np.random.default_rng(0).random((b, a.channels, a.height, a.width), dtype=np.float32)
        session.run(None, {name: inputs[b]})
    t = time.perf_counter(); session.run(None, {name: inputs[b]})
    ms = (time.perf_counter() - t) * 1e3
    cpu = time.process_time()
    print(f"forward_ms={ms:.3f} cpu_ms={(cpu - last_cpu) * 1e3:.3f}", flush=True)
    last_cpu = cpu
