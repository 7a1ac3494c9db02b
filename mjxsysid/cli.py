"""`mjxsysid` command line: scripted experiment runs.

    mjxsysid demo [--out DIR]                      the CPU demo (quick start)
    mjxsysid fly --vehicle V.json --controller oracle|nominal --reference hover|lemniscate|minsnap
                 [--period S] [--duration S] [--force-step FX,FY,FZ] [--force-sigma S]
                 [--seed N] [--gains naive|baseline] [--video] --out DIR
    mjxsysid fly --prior default --vehicles 100 --controller oracle ...   a batch from the prior
    mjxsysid fly --policy xadap --weights DIR ...   any frozen latent policy (NAME or a path)
    mjxsysid collect | train-cfm | evaluate-decoder | decode | replay | demo  [--policy NAME|PATH]
    mjxsysid export [--weights policy.npz] --out policy.onnx   the policy as ONNX, checked in onnxruntime

Policies: ``--policy mjxsysid`` (the shipped one; the default), ``--policy xadap --weights DIR``
(the released Extreme-Adaptation policy: its folder or a converted .npz; $MJXSYSID_XADAP_DIR is
the fallback), or ``--policy PATH`` (recognised from its contents).

Errors in inputs (files, arguments) are reported in one line on stderr with exit status 2.
Heavy imports happen after argument parsing, so ``--help`` is instant.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path


def _triple(text: str):
    try:
        vals = [float(x) for x in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected three comma-separated numbers FX,FY,FZ, got {text!r}")
    if len(vals) != 3:
        raise argparse.ArgumentTypeError(f"expected three comma-separated numbers FX,FY,FZ, got {text!r}")
    return tuple(vals)


def _positive(text: str):
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}")
    if not v > 0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {text}")
    return v


def _nonneg(text: str):
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}")
    if not v >= 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {text}")
    return v


def _add_policy(p, what="the frozen latent policy"):
    p.add_argument("--policy", default=None, metavar="NAME|PATH",
                   help=f"{what}: mjxsysid (shipped, default), xadap (with --weights DIR), or a path")
    p.add_argument("--weights", type=Path, default=None,
                   help="weights of the named policy (mjxsysid: policy.npz or run folder; xadap: the "
                        "folder of the released files or a converted .npz)")


PRIOR_CHOICES = ("default", "slow_actuators", "wide_actuators", "xadap")


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="mjxsysid", description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="command", required=True)

    d = sub.add_parser("demo", help="CPU demo on the paper's vehicle (plots, video, summary)")
    d.add_argument("--out", type=Path, default=Path("out/demo"), help="output folder (default out/demo)")
    d.add_argument("--no-video", action="store_true", help="skip the offscreen video")
    d.add_argument("--vehicles", type=int, default=16, help="prior vehicles in the comparison (default 16)")
    _add_policy(d)

    f = sub.add_parser("fly", help="fly one vehicle under a controller and reference")
    f.add_argument("--vehicle", type=Path, default=None,
                   help="vehicle JSON file (default: the paper's hardware vehicle)")
    f.add_argument("--prior", choices=PRIOR_CHOICES, default=None,
                   help="instead of --vehicle: fly --vehicles vehicles drawn from this prior (seeded; "
                        "xadap: the released policy's training distribution)")
    f.add_argument("--vehicles", type=int, default=100, help="with --prior: how many (default 100)")
    f.add_argument("--controller", choices=("oracle", "nominal", "policy", "xadap"), default=None,
                   help="oracle: K_θ with the true θ (default without --policy); nominal: K_θ with "
                        "the paper vehicle's θ; policy: the latent policy named by --policy (default "
                        "with --policy); xadap: short for --controller policy --policy xadap")
    _add_policy(f)
    f.add_argument("--reference", choices=("hover", "lemniscate", "minsnap"), default="lemniscate")
    f.add_argument("--period", type=_positive, default=10.0, help="lemniscate period, s (default 10)")
    f.add_argument("--duration", type=_positive, default=None,
                   help="flight duration, s (default: one period / 5 s)")
    f.add_argument("--force-step", type=_triple, default=(0.0, 0.0, 0.0), metavar="FX,FY,FZ",
                   help="constant world force, N, from --force-step-time on")
    f.add_argument("--force-step-time", type=_nonneg, default=1.0, help="s (default 1)")
    f.add_argument("--force-sigma", type=_nonneg, default=0.0,
                   help="std of an i.i.d. Gaussian world force per control step, N")
    f.add_argument("--gains", choices=("naive", "baseline"), default="baseline")
    f.add_argument("--seed", type=int, default=0)
    f.add_argument("--video", action="store_true", help="also render DIR/flight.mp4")
    f.add_argument("--out", type=Path, required=True, help="output folder")
    t = sub.add_parser("train-policy", help="train the unified adaptive policy (GPU recommended)")
    t.add_argument("--config", type=Path, default=None,
                   help="JSON file of TrainConfig overrides (default: the shipped policy's config)")
    t.add_argument("--out", type=Path, default=Path("runs/policy"), help="run folder (checkpoints, log, policy.npz)")
    t.add_argument("--iterations", type=int, default=None, help="override config.iterations")
    t.add_argument("--num-envs", type=int, default=None, help="override config.num_envs")
    t.add_argument("--seed", type=int, default=None, help="override config.seed")
    t.add_argument("--no-resume", action="store_true", help="start afresh even if DIR/checkpoint.npz exists")
    e = sub.add_parser("evaluate-policy", help="evaluate an adaptive policy (tracking, lemniscate, latent health)")
    e.add_argument("--weights", type=Path, default=None, help="policy.npz or run folder (default: shipped); "
                   "mjxsysid's policies only (training diagnostics need its μ encoder)")
    e.add_argument("--vehicles", type=int, default=1000)
    e.add_argument("--seed", type=int, default=0)
    e.add_argument("--fast", action="store_true", help="the quick latent/lemniscate evaluation of training "
                   "trials (probes on 2 x VEHICLES, lemniscate on VEHICLES)")
    e.add_argument("--out", type=Path, required=True, help="writes OUT/eval.json")
    c = sub.add_parser("collect", help="collect (θ, ẑ) pairs from a frozen policy in closed-loop flight")
    c.add_argument("--out", type=Path, required=True, help="writes OUT/pairs.npz")
    _add_policy(c)
    c.add_argument("--train", type=int, default=20_000, help="training pairs (default 20000)")
    c.add_argument("--test", type=int, default=2_000, help="held-out pairs (default 2000)")
    c.add_argument("--prior", choices=PRIOR_CHOICES, default=None,
                   help="vehicle prior (default: the one its shipped decoders are trained on: wide_actuators "
                        "for mjxsysid (its training prior with τ_m up to 0.10 s), xadap for xadap)")
    c.add_argument("--batch", type=int, default=2_000, help="vehicles per batched flight")
    c.add_argument("--seed", type=int, default=0)
    c.add_argument("--seconds", type=_positive, default=10.0,
                   help="flight length, s: the latent is recorded at 10 Hz over it (default 10)")
    c.add_argument("--manoeuvres", default="lemniscate,minsnap,hover_step",
                   help="comma-separated manoeuvres drawn per vehicle (default: lemniscate,minsnap,hover_step)")
    c.add_argument("--single-latent", action="store_true",
                   help="the shipped single-latent pairs instead: 1.5 s lemniscates, ẑ at the end, no trajectories")
    tc = sub.add_parser("train-cfm", help="train the CFM and Regression decoders on (θ, ẑ) pairs")
    tc.add_argument("--pairs", type=Path, required=True, help="pairs.npz from `mjxsysid collect` (or its folder)")
    tc.add_argument("--out", type=Path, required=True,
                    help="writes OUT/cfm.npz, OUT/regression.npz (and OUT/cfm_seq.npz, see --kinds)")
    tc.add_argument("--epochs", type=int, default=None, help="override CFMConfig.epochs (default 100)")
    tc.add_argument("--width", type=int, default=None, help="override CFMConfig.width (default 512)")
    tc.add_argument("--batch", type=int, default=None, help="override CFMConfig.batch (default 256)")
    tc.add_argument("--no-resume", action="store_true",
                    help="start afresh even if OUT holds checkpoints or decoders of an earlier run")
    tc.add_argument("--kinds", default=None,
                    help="comma-separated decoders to train: cfm, regression, cfm_seq (default: all three when "
                         "the pairs hold latent trajectories, else cfm,regression)")
    tc.add_argument("--seq-epochs", type=int, default=None, help="epochs of the sequence decoder (default: --epochs)")
    tc.add_argument("--coords", choices=("theta", "identifiable"), default=None,
                    help="coordinates the decoders learn in: identifiable (default: a log-linear reparametrisation "
                         "with log thrust-to-weight and log angular authorities as axes) or theta (normalised θ)")
    _add_policy(tc, "check that the pairs come from this policy")
    ed = sub.add_parser("evaluate-decoder", help="calibration of the decoders on held-out pairs")
    ed.add_argument("--decoders", type=Path, required=True,
                    help="folder with cfm.npz and regression.npz and/or cfm_seq.npz (the sequence decoder; "
                         "a cfm.npz alone is only its single-latent reference)")
    ed.add_argument("--pairs", type=Path, required=True)
    ed.add_argument("--cases", type=int, default=1000)
    ed.add_argument("--no-paper-flight", action="store_true",
                    help="skip flying the paper vehicle (its posterior plots / 10 s lemniscate figures)")
    ed.add_argument("--samples", type=int, default=200)
    _add_policy(ed, "policy whose latent of the paper vehicle is decoded for the marginals plot "
                    "(default: the one that made the pairs)")
    dc = sub.add_parser("decode", help="fly a vehicle (or replay a log) with the policy and decode its latent")
    dc.add_argument("--vehicle", type=Path, default=None, help="vehicle JSON (default: the paper vehicle)")
    dc.add_argument("--log", type=Path, default=None, help="decode a recorded flight instead (CSV, see README)")
    dc.add_argument("--reference", choices=("hover", "lemniscate", "minsnap"), default="lemniscate")
    dc.add_argument("--period", type=_positive, default=10.0)
    dc.add_argument("--duration", type=_positive, default=None)
    dc.add_argument("--samples", type=int, default=100, help="decoded models per latent (default 100)")
    dc.add_argument("--rate", type=_positive, default=10.0, help="decoding rate, Hz (default 10)")
    dc.add_argument("--window", default="flight",
                    help="what each decoded posterior conditions on: 'flight' (default: every latent flown so far, "
                         "sequence decoder), 'instant' (the current latent only) or SECONDS (a sliding window)")
    _add_policy(dc)
    dc.add_argument("--decoders", type=Path, default=None,
                    help="folder with cfm.npz and regression.npz, and cfm_seq.npz for --window flight|SECONDS "
                         "(default: the policy's shipped decoders)")
    dc.add_argument("--seed", type=int, default=0)
    dc.add_argument("--video", action="store_true", help="render the true vehicle with decoded ghosts")
    dc.add_argument("--out", type=Path, required=True)
    rp = sub.add_parser("replay", help="action replay: K_θ̂ from decoded θ̂ vs the policy's motor commands")
    _add_policy(rp)
    rp.add_argument("--decoders", type=Path, default=None,
                    help="folder with cfm.npz and regression.npz (default: the policy's shipped decoders)")
    rp.add_argument("--flights", default=",".join(FLIGHT_NAMES),
                    help=f"comma-separated subset of {','.join(FLIGHT_NAMES)} (default: all)")
    rp.add_argument("--vehicles", type=int, default=0,
                    help="also replay this many vehicles of the policy's own prior (default 0: paper vehicle only)")
    rp.add_argument("--samples", type=int, default=16, help="CFM samples per update for the mean action (default 16)")
    rp.add_argument("--rate", type=_positive, default=10.0, help="decoder update rate, Hz (default 10)")
    rp.add_argument("--cutoff", type=_positive, default=5.0, help="low-pass cut-off for the PCC, Hz (default 5)")
    rp.add_argument("--seed", type=int, default=0)
    rp.add_argument("--out", type=Path, required=True)
    tn = sub.add_parser("tune", help="fly a vehicle with the online predictive tuner and compare methods")
    tn.add_argument("--vehicle", type=Path, default=None, help="vehicle JSON (default: the paper vehicle)")
    tn.add_argument("--reference", choices=("lemniscate", "minsnap"), default="lemniscate")
    tn.add_argument("--period", type=_positive, default=10.0, help="lemniscate period, s (default 10)")
    tn.add_argument("--duration", type=_positive, default=None,
                    help="flight duration, s (default: one period / 5 s; --quick: 2 s)")
    tn.add_argument("--methods", default="naive,baseline,cfm,nominal_cem,oracle_cem",
                    help="comma-separated subset of naive,baseline,cfm,nominal_cem,oracle_cem")
    tn.add_argument("--models", type=int, default=None, help="K decoded models per update (default 16; quick 4)")
    tn.add_argument("--candidates", type=int, default=None, help="N candidate gains per CEM iteration (default 32; quick 8)")
    tn.add_argument("--iterations", type=int, default=None, help="CEM iterations per update (default 2)")
    tn.add_argument("--horizon", type=_positive, default=None, help="predictive horizon, s (default 0.5; quick 0.3)")
    tn.add_argument("--rate", type=_positive, default=10.0, help="tuner updates per second (default 10)")
    tn.add_argument("--quick", action="store_true", help="small settings for a CPU run of minutes")
    tn.add_argument("--seed", type=int, default=0)
    _add_policy(tn)
    tn.add_argument("--decoders", type=Path, default=None, help="folder with cfm.npz (default: the policy's)")
    tn.add_argument("--video", action="store_true", help="also render the tuned vs untuned (naive) flight side by side")
    tn.add_argument("--out", type=Path, required=True)
    ex = sub.add_parser("experiment", help="run one of the paper's experiments (results.json, results.md, PNGs)")
    ex.add_argument("name", help="tune-nominal | tune-slow | tune-lemniscate | robustness | payload | replay")
    ex.add_argument("--quick", action="store_true", help="small CPU version (minutes; a smoke test)")
    ex.add_argument("--cpu", action="store_true",
                    help="tune-*: the full protocol with fewer vehicles and smaller ensembles (tens of minutes on a CPU)")
    ex.add_argument("--seed", type=int, default=0)
    _add_policy(ex)
    ex.add_argument("--decoders", type=Path, default=None,
                    help="folder with cfm.npz and regression.npz (default: the policy's shipped decoders)")
    ex.add_argument("--out", type=Path, required=True)
    xp = sub.add_parser("export", help="write the policy as ONNX (fixed batch 1 + dynamic batch), check it in onnxruntime")
    _add_policy(xp, "the policy to export")
    xp.add_argument("--out", type=Path, required=True,
                    help="NAME.onnx (batch 1); also writes NAME_dynamic.onnx, NAME.onnx.json, NAME_testvectors.npz")
    xp.add_argument("--seconds", type=_positive, default=0.5,
                    help="closed-loop flight of the paper vehicle whose inputs check the files (default 0.5)")
    xp.add_argument("--calls", type=int, default=2000, help="onnxruntime calls per latency median (default 2000)")
    for sp in sub.choices.values():
        sp.add_argument("-q", "--quiet", action="store_true",
                        help="no progress bars or progress messages (results and errors still print)")
    return p


FLIGHT_NAMES = ("lemniscate_5s", "lemniscate_10s", "lemniscate_15s", "hover")  # replay.FLIGHTS (light import)


def _policy_ref(args):
    from mjxsysid.policy.interface import resolve_policy
    return resolve_policy(args.policy or "mjxsysid", args.weights)


def cmd_replay(args) -> int:
    from mjxsysid.analysis.replay import run_replay
    flights = tuple(f.strip() for f in args.flights.split(",") if f.strip())
    res = run_replay(args.out, policy=_policy_ref(args), decoders=args.decoders, vehicles=args.vehicles,
                     flights=flights, rate=args.rate, samples=args.samples, cutoff_hz=args.cutoff,
                     seed=args.seed, log=lambda m: _echo(m, file=sys.stderr))
    print(json.dumps({n: e["paper_vehicle"] for n, e in res["flights"].items()}))
    print(f"wrote {args.out}/replay.json, replay.md, replay_summary.png, replay_<flight>.png", file=sys.stderr)
    return 0


def cmd_decode(args) -> int:
    if args.video:
        _prepare_render()
    from mjxsysid import params as P
    from mjxsysid.analysis.decode import run_decode
    if args.log is not None and args.vehicle is not None:
        raise ValueError("give either --vehicle or --log, not both")
    from mjxsysid.analysis.decode import parse_window
    window = parse_window(args.window)
    theta = None if args.log else (P.load_vehicle(args.vehicle) if args.vehicle else P.paper_hardware())
    summary = run_decode(args.out, theta=theta, log=args.log, reference=args.reference, period=args.period,
                         duration=args.duration, samples=args.samples, rate=args.rate, policy=_policy_ref(args),
                         decoders=args.decoders, seed=args.seed, video=args.video, window=window,
                         echo=lambda m: _echo(m, file=sys.stderr))
    print(json.dumps({k: v for k, v in summary.items() if k in P.IDENTIFIABLE_NAMES}))
    print(f"wrote {args.out}/decoded.npz, summary.json, marginals.png, decoded_over_time.png"
          + (", decoded.mp4" if args.video else ""), file=sys.stderr)
    return 0


def cmd_train_cfm(args) -> int:
    import dataclasses

    from mjxsysid.cfm.pipeline import train_decoders
    from mjxsysid.cfm.train import CFMConfig
    if args.policy is not None or args.weights is not None:
        from mjxsysid.policy.collect import load_pairs
        want = _policy_ref(args)
        got = load_pairs(args.pairs)[1].get("weights_sha256")
        if got != want.sha256():
            raise ValueError(f"{args.pairs}: these pairs were not collected with {want.label}")
    over = {k: v for k, v in (("epochs", args.epochs), ("width", args.width), ("batch", args.batch),
                              ("coords", args.coords)) if v is not None}
    cfg = dataclasses.replace(CFMConfig(), **over)
    kinds = None if args.kinds is None else tuple(k.strip() for k in args.kinds.split(",") if k.strip())
    seq_cfg = {"epochs": args.seq_epochs} if args.seq_epochs is not None else None
    res = train_decoders(args.pairs, args.out, cfg, kinds=kinds, seq_cfg=seq_cfg, log=_echo,
                         resume=not args.no_resume)
    print(json.dumps({k: {kk: v[kk] for kk in ("wall_s", "final_train_loss", "final_val_loss", "steps_per_s")}
                      for k, v in res.items()}))
    return 0


def cmd_evaluate_decoder(args) -> int:
    import numpy as np

    from mjxsysid import params as P
    from mjxsysid.cfm.pipeline import evaluate_decoders
    from mjxsysid.policy.collect import latents_in_flight, load_pairs
    from mjxsysid.policy.interface import resolve_policy
    import jax
    if args.policy is None and args.weights is None:
        meta = load_pairs(args.pairs)[1]
        kind = meta.get("policy", meta.get("controller", "mjxsysid"))  # older pairs: "controller"
        w = meta.get("weights")
        if w is not None and not Path(w).exists():
            if kind != "mjxsysid":
                raise ValueError(f"{args.pairs} was collected with {kind} weights at {w}, not found here: "
                                 f"pass --policy {kind} --weights PATH")
            w = None
        ref = resolve_policy(kind, w)
    else:
        ref = _policy_ref(args)
    paper_zhat = paper_traj = None
    if (args.decoders / "cfm.npz").is_file() and (args.decoders / "regression.npz").is_file() \
            and not args.no_paper_flight:
        z, failed = latents_in_flight(ref, np.repeat(P.PAPER_HARDWARE[None], 2, 0), jax.random.PRNGKey(0))
        paper_zhat = z[0]
    if (args.decoders / "cfm_seq.npz").is_file() and not args.no_paper_flight:  # the paper vehicle after a 10 s lemniscate, ẑ at 10 Hz
        from mjxsysid.analysis.decode import decode_indices
        from mjxsysid.analysis.flight import fly_vehicles, one_flight
        one = one_flight(fly_vehicles(P.PAPER_HARDWARE, controller="policy", policy=ref, reference="lemniscate",
                                      period=10.0)[0])
        idx = decode_indices(one.time, 10.0)
        paper_traj = (np.asarray(one.latent)[idx], np.asarray(one.time)[idx])
    rep = evaluate_decoders(args.decoders, args.pairs, n_cases=args.cases, n_samples=args.samples,
                            paper_zhat=paper_zhat, paper_traj=paper_traj, log=_echo)
    brief = {}
    if "energy_score" in rep:
        brief = {"coverage_mean": rep["coverage_mean"], "calibrated": rep["calibrated_within_5_points"],
                 "energy_score": rep["energy_score"], "c2st": rep["c2st_nearby_latents"]["mean_accuracy"]}
    if "sequence" in rep:
        sq = rep["sequence"]
        brief["sequence"] = {"energy_score": {k: v["energy_score"] for k, v in sq["windows"].items()},
                             "energy_ratio_flight_vs_single": sq["energy_ratio_flight_vs_single"],
                             "targets": sq["targets"],
                             "paper_vehicle": sq.get("paper_vehicle", {}).get("targets")}
    print(json.dumps(brief))
    figs = ", sbc_ranks.png" + (", paper_vehicle_posterior.png" if paper_zhat is not None else "") if "energy_score" in rep else ""
    print(f"wrote {args.decoders}/decoder_eval.json{figs}", file=sys.stderr)
    return 0


def cmd_collect(args) -> int:
    from mjxsysid.policy.collect import collect
    ref = _policy_ref(args)
    _echo(f"collecting {args.train} + {args.test} (θ, ẑ) pairs with {ref.label}")
    manoeuvres = tuple(m.strip() for m in args.manoeuvres.split(",") if m.strip())
    path = collect(args.out, policy=ref, n_train=args.train,
                   n_test=args.test, prior=args.prior, seed=args.seed, batch=args.batch,
                   seconds=None if args.single_latent else args.seconds, manoeuvres=manoeuvres,
                   log=_echo)
    print(f"wrote {path}", file=sys.stderr)
    return 0


def cmd_evaluate_policy(args) -> int:
    from mjxsysid.policy.evaluate import evaluate_policy
    if args.vehicles < 10:
        raise ValueError(f"--vehicles must be >= 10 (linear probes need data), got {args.vehicles}")
    args.out.mkdir(parents=True, exist_ok=True)
    if args.fast:
        from mjxsysid.policy.controller import PolicyController
        from mjxsysid.policy.evaluate import fast_eval
        ctrl = PolicyController.load(args.weights)
        res = fast_eval(ctrl.params, n_probe=2 * args.vehicles, n_lem=args.vehicles, seed=args.seed,
                        phi_every=ctrl.phi_every, log=_echo)
        (args.out / "eval.json").write_text(json.dumps(res, indent=2) + "\n")
        print(json.dumps(res["summary"]))
        print(f"wrote {args.out}/eval.json", file=sys.stderr)
        return 0
    res = evaluate_policy(args.weights, n=args.vehicles, seed=args.seed, log=_echo)
    (args.out / "eval.json").write_text(json.dumps(res, indent=2) + "\n")
    lem = res["lemniscate"]
    print(json.dumps({"success_policy": lem["policy"]["success_rate"],
                      "pos_rmse_policy": lem["policy"]["pos_rmse_m"]["mean"],
                      "pos_rmse_oracle": lem["oracle"]["pos_rmse_m"]["mean"],
                      "rmse_ratio": lem.get("rmse_ratio_policy_over_oracle"),
                      "z_err_rel": res["latent"]["z_err_rel"]}))
    print(f"wrote {args.out}/eval.json", file=sys.stderr)
    return 0


def cmd_train_policy(args) -> int:
    from mjxsysid.policy.train import TrainConfig, train
    cfg_dict = TrainConfig().to_dict()
    if args.config is not None:
        if not args.config.is_file():
            raise FileNotFoundError(f"config file not found: {args.config}")
        try:
            over = json.loads(args.config.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError) as e:
            raise ValueError(f"{args.config}: not valid JSON ({e})") from None
        if not isinstance(over, dict) or not isinstance(over.get("env", {}), dict):
            raise ValueError(f"{args.config}: expected a JSON object of TrainConfig keys (and an 'env' object)")
        env = dict(cfg_dict["env"], **over.pop("env", {}))
        cfg_dict.update(over)
        cfg_dict["env"] = env
    for k, v in (("iterations", args.iterations), ("num_envs", args.num_envs), ("seed", args.seed)):
        if v is not None:
            cfg_dict[k] = v
    try:
        cfg = TrainConfig.from_dict(cfg_dict)
    except TypeError as e:  # e.g. an unknown key of the env section
        raise ValueError(f"{args.config or 'training config'}: {e}") from None
    _echo(f"training: {cfg.num_envs} envs × {cfg.unroll} steps × {cfg.iterations} iterations "
          f"= {cfg.num_envs * cfg.unroll * cfg.iterations / 1e6:.1f} M env steps -> {args.out}")
    res = train(cfg, args.out, resume=not args.no_resume, log=_echo)
    print(json.dumps({"wall_s": res["wall_s"], **{k: res["stats"][k] for k in
                      ("reward", "rate_err", "thrust_err", "latent_err_rel", "latent_min_std")}}))
    print(f"wrote {args.out}/policy.npz", file=sys.stderr)
    return 0


def _prepare_render():
    from mjxsysid.render.video import headless_env
    headless_env()


def cmd_fly(args) -> int:
    if args.video:
        _prepare_render()
    from mjxsysid import params as P
    from mjxsysid.analysis.flight import fly_vehicles, one_flight, save_flight, write_metrics
    from mjxsysid.render.plots import plot_trajectory

    if args.controller is None:
        args.controller = "policy" if (args.policy or args.weights) else "oracle"
    if args.controller == "xadap":
        args.controller, args.policy = "policy", args.policy or "xadap"
        if args.policy != "xadap":
            raise ValueError(f"--controller xadap conflicts with --policy {args.policy}")
    if args.controller == "policy":
        args.policy = _policy_ref(args)
    elif args.policy is not None or args.weights is not None:
        raise ValueError(f"--policy / --weights do not apply to --controller {args.controller}")
    if args.prior is not None:
        if args.vehicle is not None:
            raise ValueError("give either --vehicle or --prior, not both")
        if args.vehicles < 1:
            raise ValueError(f"--vehicles must be >= 1, got {args.vehicles}")
        return _fly_prior(args)
    theta = P.load_vehicle(args.vehicle) if args.vehicle else P.paper_hardware()
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.time()
    flight, m, duration = fly_vehicles(
        theta, controller=args.controller, reference=args.reference, period=args.period,
        duration=args.duration, gains=args.gains, force_step=args.force_step,
        force_step_time=args.force_step_time, force_sigma=args.force_sigma, seed=args.seed,
        policy=args.policy)
    save_flight(flight, theta, out / "flight.npz")
    info = {"vehicle": str(args.vehicle or "paper_hardware"), "controller": _ctrl_label(args),
            "reference": args.reference, "duration_s": duration, "gains": args.gains,
            "seed": args.seed}
    d = write_metrics(m, out / "metrics.json", extra=info)
    one = one_flight(flight)
    plot_trajectory(one.frame, out / "tracking.png", reference=one.ref_pos,
                    title=f"{_ctrl_label(args)}, {args.reference}, {Path(info['vehicle']).stem}")
    if args.video:
        from mjxsysid.render.video import render_rollout
        render_rollout(theta, one.frame, out / "flight.mp4", reference=one.ref_pos)
    print(json.dumps({k: d[k] for k in ("pos_rmse_m", "max_pos_err_m", "heading_rmse_deg",
                                         "lateral_rmse_m", "vertical_rmse_m", "saturation_frac",
                                         "failed")}))
    print(f"wrote {out}/flight.npz, tracking.png, metrics.json"
          + (", flight.mp4" if args.video else "") + f" ({time.time() - t0:.1f} s)", file=sys.stderr)
    return 0


def _ctrl_label(args) -> str:
    return f"policy {args.policy.label}" if args.controller == "policy" else f"{args.controller} K_θ"


def _fly_prior(args) -> int:
    """`fly --prior NAME --vehicles N`: a batch from the prior; summary + per-vehicle metrics."""
    import jax
    import numpy as np

    from mjxsysid import params as P
    from mjxsysid.analysis.flight import (fly_vehicles, one_flight, random_minsnaps, save_flight,
                                          write_metrics)
    from mjxsysid.analysis.harness import metrics_to_host
    from mjxsysid.render.plots import plot_trajectory

    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    theta = np.asarray(P.get_prior(args.prior).sample(jax.random.PRNGKey(args.seed), args.vehicles))
    refs = random_minsnaps(args.vehicles, args.seed, args.duration or 5.0) if args.reference == "minsnap" else None
    flight, m, duration = fly_vehicles(
        theta, controller=args.controller, reference=args.reference, period=args.period,
        duration=args.duration, gains=args.gains, force_step=args.force_step,
        force_step_time=args.force_step_time, force_sigma=args.force_sigma, seed=args.seed, refs=refs,
        policy=args.policy)
    save_flight(flight, theta, out / "flight.npz")
    info = {"prior": args.prior, "vehicles": args.vehicles, "controller": _ctrl_label(args),
            "reference": args.reference, "duration_s": duration, "gains": args.gains, "seed": args.seed,
            "per_vehicle": metrics_to_host(m), "theta": theta.tolist()}
    d = write_metrics(m, out / "metrics.json", index=None, extra=info)
    one = one_flight(flight)
    plot_trajectory(one.frame, out / "tracking.png", reference=one.ref_pos,
                    title=f"{_ctrl_label(args)}, {args.reference}, first of {args.vehicles} {args.prior}-prior vehicles")
    print(json.dumps({k: d[k] for k in ("n", "success_rate", "pos_rmse_m", "heading_rmse_deg",
                                         "saturation_frac")}))
    print(f"wrote {out}/metrics.json (summary + per-vehicle), flight.npz and tracking.png (first vehicle)",
          file=sys.stderr)
    return 0


def cmd_tune(args) -> int:
    import dataclasses

    if args.video:
        _prepare_render()
    from mjxsysid import params as P
    from mjxsysid.analysis.flight import broadcast, make_reference
    from mjxsysid.experiments.tuning import FULL_TUNER, QUICK_TUNER
    from mjxsysid.sim import Quadrotor
    from mjxsysid.tune.compare import check_methods, compare_methods, plot_gains, plot_tracking, results_dict

    methods = check_methods(m.strip() for m in args.methods.split(",") if m.strip())
    base = QUICK_TUNER if args.quick else FULL_TUNER
    cem = base.cem
    if args.candidates is not None or args.iterations is not None:
        cem = dataclasses.replace(cem, **{k: v for k, v in (("candidates", args.candidates),
                                                            ("iterations", args.iterations)) if v is not None})
    over = {k: v for k, v in (("models", args.models), ("horizon", args.horizon), ("rate", args.rate)) if v is not None}
    cfg = dataclasses.replace(base, cem=cem, **over)
    theta = P.load_vehicle(args.vehicle) if args.vehicle else P.paper_hardware()
    duration = args.duration or (2.0 if args.quick else (args.period if args.reference == "lemniscate" else 5.0))
    if cfg.horizon > duration:
        raise ValueError(f"--horizon {cfg.horizon:g} s is longer than the flight ({duration:g} s)")
    policy = _policy_ref(args)
    decoder = None
    if "cfm" in methods:
        from mjxsysid.analysis.decode import load_decoders
        decoder = load_decoders(args.decoders, policy, warn=lambda m: print(m, file=sys.stderr))[0]
    ref, _ = make_reference(args.reference, period=args.period, duration=duration, seed=args.seed)
    sim = Quadrotor()
    steps = int(round(duration / sim.config.dt))
    args.out.mkdir(parents=True, exist_ok=True)
    t0 = time.time()
    res = compare_methods(theta[None], broadcast(ref, 1), steps=steps, methods=methods, cfg=cfg, policy=policy,
                          decoder=decoder, sim=sim, seed=args.seed,
                          log=lambda m: _echo(m, file=sys.stderr))
    d = results_dict(res, index=0)
    info = {"vehicle": str(args.vehicle or "paper_hardware"), "reference": args.reference,
            "period_s": args.period, "duration_s": duration, "policy": policy.label, "seed": args.seed,
            "tuner": dataclasses.asdict(cfg), "wall_s": round(time.time() - t0, 1)}
    (args.out / "metrics.json").write_text(json.dumps({**d, "config": info}, indent=2) + "\n")
    name = Path(info["vehicle"]).stem
    plot_gains(res, args.out / "gains.png", title=f"gains over time, {name}, {args.reference}")
    plot_tracking(res, args.out / "tracking.png", title=f"tracking, {name}, {args.reference}")
    wrote = "metrics.json, gains.png, tracking.png"
    if args.video:
        _tune_video(res, theta, args.out)
        wrote += ", tuned_vs_untuned.mp4"
    print(json.dumps({k: {m: v[m] for m in ("pos_rmse_m", "max_pos_err_m", "heading_rmse_deg", "failed")}
                      for k, v in d.items()}))
    print(f"wrote {args.out}/{wrote}", file=sys.stderr)
    return 0


def _tune_video(res, theta, out):
    """The tuned flight (CFM-tuned, else the first CEM method) beside the untuned (naive) one."""
    import tempfile

    from mjxsysid.render.video import render_rollout, side_by_side
    from mjxsysid.tune.tuner import CEM_METHODS
    tuned = next((m for m in ("cfm",) + CEM_METHODS if m in res), None)
    untuned = "naive" if "naive" in res else ("baseline" if "baseline" in res else None)
    if tuned is None or untuned is None:
        raise ValueError("--video needs a tuned method (cfm, nominal_cem or oracle_cem) and naive or baseline")
    with tempfile.TemporaryDirectory() as tmp:
        paths = []
        for m in (untuned, tuned):
            fl = res[m]["tuned"].flight
            frames = type(fl.frame)(*[a[0] for a in fl.frame])
            paths.append(render_rollout(theta, frames, Path(tmp) / f"{m}.mp4", width=480, height=360,
                                        reference=fl.ref_pos[0]))
        from mjxsysid.tune.tuner import METHOD_LABELS
        side_by_side(paths, out / "tuned_vs_untuned.mp4", labels=[METHOD_LABELS[untuned], METHOD_LABELS[tuned]])


def cmd_experiment(args) -> int:
    from mjxsysid.experiments import get_experiment
    run = get_experiment(args.name)
    if args.cpu and args.quick:
        raise ValueError("give either --quick or --cpu, not both")
    if args.cpu and not args.name.startswith("tune-"):
        raise ValueError(f"--cpu applies to the tune-* experiments, not {args.name}")
    kw = {"cpu": True} if args.cpu else {}
    if args.decoders is not None:
        import inspect
        if "decoders" not in inspect.signature(run).parameters:
            raise ValueError(f"experiment {args.name} does not take --decoders")
        if not args.decoders.is_dir():
            raise FileNotFoundError(f"--decoders: folder not found: {args.decoders}")
        kw["decoders"] = args.decoders
    res = run(args.out, quick=args.quick, policy=_policy_ref(args), seed=args.seed, **kw)
    print(json.dumps(res["numbers"].get("headline", {})))
    print(f"wrote {args.out}/results.json, results.md and figures ({res['wall_s']:.0f} s)", file=sys.stderr)
    return 0


def cmd_demo(args) -> int:
    if not args.no_video:
        _prepare_render()
    from mjxsysid.analysis.demo import run_demo
    run_demo(args.out, video=not args.no_video, n_vehicles=args.vehicles, policy=_policy_ref(args))
    return 0


def cmd_export(args) -> int:
    from mjxsysid.policy.export import ExportConfig, check_out
    check_out(args.out)
    if args.calls < 10:
        raise ValueError(f"--calls must be >= 10, got {args.calls}")
    if args.seconds < 0.1:
        raise ValueError(f"--seconds must be >= 0.1 (the check needs ẑ refreshes), got {args.seconds}")
    ref = _policy_ref(args)
    if ref.kind != "mjxsysid":
        raise ValueError(f"--policy {ref.kind}: the released Xadap policy already is ONNX (encoder.onnx, "
                         f"mlp.onnx); export writes mjxsysid's own policy")
    try:
        import jax2onnx  # noqa: F401
        import onnxruntime  # noqa: F401
    except ImportError as e:
        raise ValueError(f"export needs jax2onnx and onnxruntime ({e.name} missing): "
                         f"pip install 'mjxsysid[export]'") from None
    from mjxsysid.policy.export import run_export
    cfg = ExportConfig(flight_seconds=args.seconds, latency_calls=args.calls)
    d = run_export(ref, args.out, cfg, log=lambda m: print(m, file=sys.stderr, flush=True))
    par, lat = d["parity"], d["latency"]["batch_1"]
    print(json.dumps({"max_abs_diff": par["max_abs_diff"], "parity_ok": par["ok"],
                      "latency_us_batch1": lat["step_us"]["median_us"],
                      "latency_us_batch1_refresh": lat["refresh_step_us"]["median_us"],
                      "latency_us_batch1_mean": lat["mean_per_step_us"]}))
    print(f"onnxruntime vs JAX controller on {par['steps']} recorded steps: max abs diff "
          f"{par['max_abs_diff']:.2e} (target <= {par['tolerance']:g}); latency per step, batch 1: "
          f"{lat['step_us']['median_us']:.1f} µs, with the ẑ refresh {lat['refresh_step_us']['median_us']:.1f} µs "
          f"(median of {args.calls}; {d['latency']['runtime']})", file=sys.stderr)
    if not par["ok"]:
        print(f"mjxsysid export: parity target missed ({par['max_abs_diff']:.2e} > {par['tolerance']:g})",
              file=sys.stderr)
        return 1
    return 0


def _echo(msg, file=None):
    from mjxsysid.progress import echo
    echo(msg, file=file)


def _start_processes(args) -> None:
    """Join a multi-process run if a cluster launcher started one (mjxsysid.distributed): every
    process computes the same gathered results; only process 0 writes ``--out`` (the others
    write to a scratch folder; train-policy guards its own writes and reads the shared run
    folder to resume)."""
    from mjxsysid import distributed
    if not distributed.maybe_initialize():
        return
    import jax
    if jax.process_index() > 0 and getattr(args, "out", None) is not None and args.command != "train-policy":
        import tempfile
        args.out = Path(tempfile.mkdtemp(prefix=f"mjxsysid_p{jax.process_index()}_"))


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    from mjxsysid.progress import set_quiet
    set_quiet(True if args.quiet else None)
    handlers = {"fly": cmd_fly, "demo": cmd_demo, "train-policy": cmd_train_policy,
                "evaluate-policy": cmd_evaluate_policy, "collect": cmd_collect,
                "train-cfm": cmd_train_cfm, "evaluate-decoder": cmd_evaluate_decoder, "decode": cmd_decode,
                "replay": cmd_replay, "experiment": cmd_experiment, "export": cmd_export,
                "tune": cmd_tune}
    try:
        _start_processes(args)
        return handlers[args.command](args)
    except (ValueError, OSError) as e:  # bad inputs (FileNotFoundError is an OSError)
        print(f"mjxsysid {args.command}: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        again = (" (run the same command again to resume from the last checkpoint)"
                 if args.command in ("train-policy", "train-cfm") else "")
        print(f"mjxsysid {args.command}: interrupted{again}", file=sys.stderr)
        return 130
    finally:
        set_quiet(None)


if __name__ == "__main__":
    sys.exit(main())
