"""`mjxsysid release`: regenerate everything a release ships, in resumable stages.

The parser (``add_release``) stands beside its handler (``cmd_release``); the handler imports
what it runs when it runs: `mjxsysid --help` stays instant.
"""
from __future__ import annotations

import sys
from pathlib import Path

from mjxsysid.cli._common import echo

STAGE_NAMES = ("policy", "policy_eval", "pairs", "decoders", "seq_pairs", "seq_decoder", "decoder_eval", "noise",
               "tune_nominal", "tune_slow", "tune_slow_more", "tune_lemniscate", "studies", "fidelity",
               "posterior_calibration", "tables", "ship")  # = mjxsysid.release.stages.STAGES.names() (light import)


def add_release(sub) -> None:
    r = sub.add_parser("release", help="a release in resumable stages: policy, decoders, experiments, docs tables, "
                                       "shipped files (docs/release.md)")
    r.add_argument("--out", type=Path, required=True,
                   help="the release folder: OUT/<stage>/ and OUT/release.json (the record that resumes it)")
    r.add_argument("--stages", default=None, metavar="S1,S2",
                   help=f"run only these stages (their dependencies must be done); stages: {', '.join(STAGE_NAMES)}")
    r.add_argument("--force", action="append", default=None, metavar="STAGE",
                   help="rerun this stage from scratch even if done (repeatable)")
    r.add_argument("--list", action="store_true", help="print the stages with their status and recorded times, "
                                                       "run nothing")
    r.add_argument("--tiny", action="store_true",
                   help="every stage at CPU-seconds size (the tests' end-to-end release); ships into OUT/ship")
    r.add_argument("--policy-config", type=Path, default=None, metavar="PATH",
                   help="TrainConfig JSON of the policy stage (default: the package's release/configs/"
                        "policy_release.json, the default config with sensor randomisation)")
    r.add_argument("--from-policy", type=Path, default=None, metavar="POLICY.npz",
                   help="adopt these policy weights instead of training (a release of the shipped policy: "
                        "mjxsysid/pretrained/policy.npz)")
    r.add_argument("--ship-to", type=Path, default=None, metavar="ROOT",
                   help="the tree ship copies into: ROOT/mjxsysid/pretrained/, ROOT/docs/runs/<kind>/, ROOT/docs/ "
                        "(a checkout: required for the ship stage; --tiny: default OUT/ship)")
    r.add_argument("--docs-root", type=Path, default=None, metavar="ROOT",
                   help="the checkout whose generated pages the tables stage regenerates over the release's run "
                        "files (default: --ship-to's ROOT; required for the tables stage of a full release; a --tiny release "
                        "without it lays out its tree and regenerates no page)")
    r.add_argument("--allow-partial", action="store_true",
                   help="with --stages ship: ship what the done stages wrote although others are not done")
    r.set_defaults(handler=cmd_release)


def cmd_release(args) -> int:
    from mjxsysid.release.runner import Release
    from mjxsysid.release.stages.policy import config_path
    given = {}
    if args.tiny:
        given["scale"] = "tiny"
    if args.policy_config is not None:
        if not config_path(args.policy_config).is_file():
            raise FileNotFoundError(f"--policy-config: config file not found: {args.policy_config}")
        given["policy_config"] = str(args.policy_config)
    if args.from_policy is not None:
        if not args.from_policy.is_file():
            raise FileNotFoundError(f"--from-policy: policy weights not found: {args.from_policy}")
        given["from_policy"] = str(args.from_policy)
    if args.policy_config is not None and args.from_policy is not None:
        raise ValueError("give either --policy-config (train) or --from-policy (adopt), not both")
    if args.out.exists() and not args.out.is_dir():
        raise ValueError(f"--out {args.out}: is a file, not a release folder")
    if args.list and not (args.out / "release.json").is_file():
        raise FileNotFoundError(f"--list: no release in {args.out} (no release.json)")
    rel = Release(args.out, given, ship_to=args.ship_to, docs_root=args.docs_root, log=echo)
    if args.list:
        print(rel.table())
        return 0
    select = [args.stages] if args.stages is not None else None
    todo = rel.plan(select, args.force or (), args.allow_partial)   # errors before anything is written
    if "policy" in todo and not rel.options.from_policy and not config_path(rel.options.policy_config).is_file():
        raise FileNotFoundError(f"policy config file not found: {rel.options.policy_config}")
    if "tables" in todo and rel.docs_root is None and rel.options.scale != "tiny":
        raise ValueError("stage tables regenerates the pages of a checkout: give its root (--docs-root ROOT)")
    if "ship" in todo and rel.ship_to is None:
        raise ValueError("stage ship copies into a checkout: give its root (--ship-to ROOT)")
    ran = rel.run(select, args.force or (), args.allow_partial)
    print(rel.table())
    if ran:
        print(f"wrote {args.out}/release.json (stages run: {', '.join(ran)})", file=sys.stderr)
    return 0
