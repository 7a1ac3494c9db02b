"""Whether N logs refined by NUTS in one batch finish on a CPU (jaxlib 0.10's batched LAPACK kernels in blackjax's
dense metric and lineax's Cholesky). From the repository root: python docs/runs/measurements/log-grounded/batched/cpu_batch_probe.py 32"""
import sys, time
from mjxsysid import theta as P
from mjxsysid.identify.inference import log_grounded_posteriors
sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parents[5] / "tests"))
from support.exact_model_log import synthetic_log  # noqa
n = int(sys.argv[1])
base = P.paper_hardware().copy()
recs = [synthetic_log(base, seconds=3.0, gyro_noise=0.05, acc_noise=0.5, seed=k) for k in range(n)]
t = time.time()
out = log_grounded_posteriors(recs, seeds=list(range(n)), batch=n, samples=400, particles=256, draws=512,
                              calibration=None, force_smc=True, refine=True)
print(n, "logs", time.time() - t, "s", [o["method"] for o in out][:4], flush=True)
