"""The suite's fixtures. Its plugins (JAX settings, the xdist groups and queue, the workers' exit)
and helpers (paths, notebooks) are modules of tests/support/."""
import pytest

from support.paths import XADAP_DIR, require_xadap

pytest_plugins = ("support.jax_setup", "support.xdist_queue", "support.worker_exit")


@pytest.fixture(scope="session", autouse=True)
def posterior_at_test_resolution():
    """The log-grounded posterior's in-process runs (decode, the demo, the notebooks) on 1024
    importance draws and 512 SMC particles instead of 4096 and 2048: the tier checks what they
    compute, not their resolution (tests/identify runs its coverage checks on 512 particles too), and
    without the SMC's NUTS refinement unless a test asks for it (``refine=True``)."""
    from mjxsysid.identify import posterior_config as pc
    # NUTS's compiles: tests/identify/test_nuts.py and the tests that ask for it (refine=True)
    pc.DEFAULT = pc.PosteriorConfig(draws=1024, particles=512, refine=False)
    yield


@pytest.fixture
def xla_optimised_test():
    """:func:`support.jax_setup.xla_optimised` for a whole test (``@pytest.mark.usefixtures("xla_optimised_test")``)."""
    from support.jax_setup import xla_optimised
    with xla_optimised():
        yield


@pytest.fixture(scope="session")
def exact_model_posteriors():
    """What tests/identify/test_nuts.py and tests/experiments/test_sampler_reference.py read of one 4 s log
    whose likelihood's model is exact (the paper vehicle, ×5-like noise, seed 3), computed once, XLA optimised
    (run time, not compiles): the log, the SMC's posterior (400 draws), the same refined by NUTS (its retry
    as long as its first run), and a longer NUTS run from the SMC's mode and draws: the refinement's own
    program (one NUTS compile for both) at five seeds, pooled (40 chains × (200 + 50), 2,000 draws); ``ahead``:
    each program the refined call waited for and whether its thread had compiled it (runtime/ahead.py); ``exported``:
    the programs it ran from their files (runtime/exported.py)."""
    import numpy as np
    from mjxsysid import theta as P
    from mjxsysid.identify import nuts as S
    from mjxsysid.identify.inference import log_grounded_posterior
    from mjxsysid.identify.logdata import prepare
    from support.exact_model_log import exact_model_log
    from support.jax_setup import xla_optimised
    theta = P.paper_hardware().copy()
    data = prepare(exact_model_log(theta, 4.0, gyro_noise=0.05, acc_noise=0.5, seed=3))
    kw = dict(force_smc=True, seed=1, calibration=None, particles=256, samples=400)
    from support.ahead import record_exported, record_waits
    with xla_optimised(), pytest.MonkeyPatch.context() as mp:
        mp.setattr(S, "LONGER", (1, 1))      # the retry's length: test_nuts's forced retry runs it again
        with pytest.MonkeyPatch.context() as spy:
            waits = record_waits(spy)        # which programs the refined call found compiled ahead
            files = record_exported(spy)     # and which it ran from their exported files
            refined = log_grounded_posterior(data, None, refine=True, **kw)
        smc = log_grounded_posterior(data, None, refine=False, **kw)
        mode = smc["mode"]
        smc_y = np.concatenate([smc["v_raw"], smc["nuisance"][:, :4], smc["nuisance"][:, 8:]], 1)
        plans = S.refine_plans(kw["samples"])                     # the refinement's, LONGER (1, 1)
        runs = [S.nuts_reference(data, smc["nuisance"][0, 4:8], smc["weights"], np.r_[mode[:16], mode[20:]], smc_y,
                                 chains=S.CHAINS, warmup=S.WARMUP, draws=plans[0][1], seed=seed, plans=plans,
                                 max_doublings=S.MAX_DOUBLINGS) for seed in range(7, 12)]
        y = np.concatenate([r["y"] for r in runs])
        ref = {"y": y, **S.diagnostics(y, [r["divergences"] for r in runs], [r["leapfrog_mean"] for r in runs],
                                       np.concatenate([r["step_size"] for r in runs]))}
    return {"theta": theta, "data": data, "refined": refined, "smc": smc, "reference": ref, "ahead": waits,
            "exported": files}


@pytest.fixture(scope="session")
def sim():
    from mjxsysid.sim import Quadrotor
    return Quadrotor()


@pytest.fixture(scope="module")
def xadap_weights():
    require_xadap("onnx")
    from mjxsysid.policy.xadap.onnx_import import load_xadap
    return load_xadap(XADAP_DIR)


@pytest.fixture(scope="session")
def xadap_paper_recording():
    """The released policy flying the paper vehicle 2 s on a 10 s lemniscate, recorded as
    action replay needs it (IMU the policy acted on, commands, motor commands, latents). 2 s:
    the shape of notebook 01's Xadap flight, whose kernel then loads this compile from the cache."""
    from mjxsysid import theta as P
    from mjxsysid.rollout.flight import fly_vehicles, one_flight, seen_imu
    from mjxsysid.policy.interface import resolve_policy
    ref = resolve_policy("xadap", require_xadap("onnx"))
    fl, _, _ = fly_vehicles(P.PAPER_HARDWARE, controller="policy", policy=ref, reference="lemniscate",
                            period=10.0, duration=2.0)
    f = one_flight(fl)
    return ref, {"time": f.time, "imu": seen_imu(f.frame.imu), "imu_after": f.frame.imu,
                 "a_cmd": f.a_cmd, "omega_cmd": f.omega_cmd, "motor_cmd": f.frame.motor_cmd,
                 "latent": f.latent}


@pytest.fixture(scope="session")
def collected_pairs(tmp_path_factory):
    """`mjxsysid collect` on tiny sizes with the shipped policy, run once for the tests that read
    its pairs (tests/policy/test_policy.py) and latent trajectories (tests/cfm/test_sequence.py)."""
    from mjxsysid.cli import main
    from mjxsysid.policy.adaptive.controller import PRETRAINED
    if not PRETRAINED.exists():
        pytest.skip("no shipped policy weights")
    out = tmp_path_factory.mktemp("collect")
    # 4 s flights (the default 10 s: 5000 policy steps of 8 vehicles, unoptimised, were half this
    # fixture; at 2 s the random manoeuvres, sized to the flight, are too fast for some vehicles)
    assert main(["collect", "--out", str(out), "--train", "6", "--test", "2", "--batch", "8", "--seconds", "4"]) == 0
    return out
