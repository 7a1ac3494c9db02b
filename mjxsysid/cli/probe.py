"""`mjxsysid probe`: where is the policy weak?

The parser (``add_probe``) stands beside its handler (``cmd_probe``); the handler imports what it
runs when it runs: `mjxsysid --help` stays instant.
"""
from __future__ import annotations

from pathlib import Path

from mjxsysid.runtime import jsonout
from mjxsysid.cli._common import add_policy, echo, policy_ref, positive

REFERENCES = ("lemniscate", "minsnap", "force_step")  # = mjxsysid.probe.closed_loop.REFERENCES


def add_probe(sub) -> None:
    p = sub.add_parser("probe", help="search latent space for systems the policy flies badly; write weak.npz "
                                     "(input of train-policy --focus) and a report")
    p.add_argument("--out", type=Path, required=True, help="writes OUT/weak.npz, results.json, results.md, weak_vs_prior.png")
    add_policy(p)
    p.add_argument("--decoders", type=Path, default=None, help="folder with cfm.npz (default: the policy's)")
    p.add_argument("--reference", default="lemniscate",
                   help=f"what the decoded systems fly: {', '.join(REFERENCES)} (default lemniscate)")
    p.add_argument("--period", type=positive, default=None, help="lemniscate period, s (default 5)")
    p.add_argument("--duration", type=positive, default=None, help="flight length, s (default 5; quick 2)")
    p.add_argument("--samples", type=int, default=None, help="decoded systems per latent (default 8; quick 2)")
    p.add_argument("--anchors", type=int, default=None, help="prior vehicles anchoring the search (default 256; quick 16)")
    p.add_argument("--population", type=int, default=None, help="candidates per iteration (default 64; quick 8)")
    p.add_argument("--iterations", type=int, default=None, help="search iterations (default 4; quick 2)")
    p.add_argument("--keep", type=int, default=None, help="weak latents kept (default 16; quick 4)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--quick", action="store_true", help="small settings for a CPU run of minutes")
    p.set_defaults(handler=cmd_probe)


def cmd_probe(args) -> int:
    import dataclasses

    from mjxsysid.probe import ProbeConfig, run_probe
    base = ProbeConfig.quick() if args.quick else ProbeConfig()
    search = dataclasses.replace(base.search, **{k: v for k, v in (("population", args.population),
                                 ("iterations", args.iterations), ("keep", args.keep), ("seed", args.seed))
                                 if v is not None})
    over = {k: v for k, v in (("reference", args.reference), ("period", args.period), ("duration", args.duration),
                              ("samples", args.samples), ("anchors", args.anchors), ("seed", args.seed)) if v is not None}
    cfg = dataclasses.replace(base, search=search, **over)
    res = run_probe(args.out, cfg, policy=policy_ref(args), decoders=args.decoders, echo=echo)
    print(jsonout.dumps({"anchor_badness_mean": res["anchor_badness_mean"], "weak_badness": res["weak_badness"][:4],
                      "weak_systems": res["weak_systems"]}))
    echo(f"wrote {args.out}/weak.npz, results.json, results.md, weak_vs_prior.png")
    return 0
