"""Peer for `cargo xtask bench model`: ONNX Runtime on the CPU running the model exported by
`model::onnx::export` (the same folded network Burn times), with the same thread count. Not part
of CI. Needs: pip install onnxruntime numpy.

Prints one line per batch size: batch=B forward_ms=X forward_q1_ms=Q1 forward_q3_ms=Q3 version=V
(median and quartiles of --reps after a warm-up, numpy's quantile rule, as the Rust side's).
"""
import argparse, statistics, time
import numpy as np
import onnxruntime as ort

ap = argparse.ArgumentParser()
ap.add_argument("--model"); ap.add_argument("--channels", type=int, default=3)
ap.add_argument("--height", type=int); ap.add_argument("--width", type=int)
ap.add_argument("--batches"); ap.add_argument("--reps", type=int, default=3); ap.add_argument("--threads", type=int)
a = ap.parse_args()
options = ort.SessionOptions()
options.intra_op_num_threads = a.threads
options.inter_op_num_threads = 1
options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
session = ort.InferenceSession(a.model, options, providers=["CPUExecutionProvider"])
name = session.get_inputs()[0].name
for b in (int(x) for x in a.batches.split(",")):
    x = np.random.default_rng(0).random((b, a.channels, a.height, a.width), dtype=np.float32)
    session.run(None, {name: x})
    times = []
    for _ in range(a.reps):
        t = time.perf_counter(); session.run(None, {name: x}); times.append((time.perf_counter() - t) * 1e3)
    q1, med, q3 = statistics.quantiles(times, n=4, method="inclusive") if len(times) > 1 else times * 3
    print(f"batch={b} forward_ms={med:.3f} forward_q1_ms={q1:.3f} forward_q3_ms={q3:.3f} version={ort.__version__}",
          flush=True)
