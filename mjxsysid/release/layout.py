"""Where a release's files go: each shipped run kind's folder under docs/runs/, the weights under
mjxsysid/pretrained/, the figures under docs/ (paths relative to the root of the tree shipped
into: a checkout, or a release's own tree), and how files are linked and copied there.

This module is the one place that knows the docs/runs/ layout: the shipped tree
([build_tree][mjxsysid.release.stages.ship.build_tree]) and the generated pages
([mjxsysid.release.pages][]) both read it from here.
"""
from __future__ import annotations

import os
import shutil
from pathlib import Path

from mjxsysid.release.runs import STUDY_RUNS, TUNE_RUNS

PRETRAINED = "mjxsysid/pretrained"
"""Shipped weights and their provenance JSON."""
DOCS = "docs"
RUNS = "docs/runs"
KINDS = {
    # shipped by a release: docs/runs/release/, replaced whole at each ship
    "policy": "release/policy", "decoders": "release/decoders", "noise": "release/noise",
    "tuning": "release/tuning", "studies": "release/studies", "calibration": "release/calibration",
    # measured outside a release (``mjxsysid experiment NAME``), read by the generated pages
    "lag_oracle": "measurements/lag-oracle", "nobc": "measurements/nobc", "xadap": "measurements/xadap",
    "held_out": "measurements/held-out", "log_grounded": "measurements/log-grounded",
    # superseded protocols the pages show beside today's
    "previous_protocol": "archive/previous_protocol", "issue22_tuning": "archive/issue22_tuning",
}
"""Per kind of run, its folder under :data:`RUNS`."""


def run_path(kind: str, *parts: str) -> str:
    """The path (relative to the tree's root) of a run file of ``kind``: docs/runs/<kind's folder>/parts."""
    return "/".join((RUNS, KINDS[kind], *parts))


RELEASE_RUNS = f"{RUNS}/release"
"""The folder that holds exactly what the last release shipped (its run files and its record,
release.json): ``ship`` replaces it whole."""


def pretrained_path(*parts: str) -> str:
    """The path (relative to the tree's root) of a shipped weights or provenance file."""
    return "/".join((PRETRAINED, *parts))


DOCS_RUNS = (
    # (stage, path in the stage folder, path in the shipped tree)
    ("policy_eval", "eval.json", run_path("policy", "eval.json")),
    ("policy", "train_log.jsonl", run_path("policy", "train_log.jsonl")),
    ("policy_eval", "heldout", run_path("policy", "heldout")),
    ("decoder_eval", "single/decoder_eval.json", run_path("decoders", "decoder_eval.json")),
    ("decoder_eval", "single/sbc_ranks.png", run_path("decoders", "sbc_ranks.png")),
    ("decoder_eval", "single/paper_vehicle_posterior.png", run_path("decoders", "paper_vehicle_posterior.png")),
    ("decoders", "train_log.txt", run_path("decoders", "train_log.txt")),
    ("decoder_eval", "flight/decoder_eval.json", run_path("decoders", "seq_decoder_eval.json")),
    ("seq_decoder", "train_log.txt", run_path("decoders", "seq_decoder_log.txt")),
    ("noise", "noise_sensitivity.json", run_path("noise", "noise_sensitivity.json")),
    ("noise", "noise_sensitivity_low.json", run_path("noise", "noise_sensitivity_low.json")),
    *((key, r.folder, run_path("tuning", r.folder)) for key, runs in TUNE_RUNS.items() for r in runs),
    *(("studies", r.folder, run_path("studies", r.folder)) for r in STUDY_RUNS),
    ("fidelity", "closed_loop_fidelity.json", run_path("studies", "closed_loop_fidelity.json")),
    ("fidelity", "closed_loop_fidelity_same_flight.json", run_path("studies", "closed_loop_fidelity_same_flight.json")),
    *(("posterior_calibration", f, run_path("calibration", f))
      for f in ("evaluation.json", "evaluation.md", "coverage_width.png", "ranks.png")),
)
"""The run outputs the docs quote, and where in the shipped tree a release puts them."""
OPTIONAL = ("train_log.jsonl", "single/paper_vehicle_posterior.png")
"""Files of DOCS_RUNS a done stage may lack: an adopted policy has no training log; a tiny release
flies no paper vehicle."""
DOCS_FILES = (("noise", "noise_sensitivity.png", f"{DOCS}/noise_sensitivity.png"),)
"""Figures the docs pages show directly (stage, file, path in the shipped tree)."""
SHIPPED = (("policy", "policy.npz"), ("decoders", "cfm.npz"), ("decoders", "regression.npz"),
           ("seq_decoder", "cfm_seq.npz"))
"""(stage, weights file) shipped into :data:`PRETRAINED` with a provenance JSON each."""
TABLES = (("posterior_calibration", "posterior_calibration.json"),)
"""(stage, JSON file) shipped into :data:`PRETRAINED` with the provenance inside (its ``provenance``
key): the posterior calibration table."""


def shrink_pngs(path: Path) -> None:
    """Rewrite every PNG at or under ``path`` as a 256-colour palette image (a plot looks the same
    at about half the bytes): the figures docs/runs/ keeps in git."""
    from PIL import Image
    for f in ([path] if path.is_file() else sorted(path.rglob("*.png"))):
        if f.suffix == ".png":
            with Image.open(f) as im:
                small = im.convert("RGB").quantize(colors=256)
            small.save(f, "PNG", optimize=True)


def link(src: Path, dst: Path) -> None:
    """dst becomes a hard link of src (a copy where links fail); an existing dst is replaced
    atomically (linked under a temporary name, then renamed: processes running other stages at
    once may link the same file)."""
    if not src.is_file():
        raise FileNotFoundError(f"{src} not found (is its stage done?)")
    dst.parent.mkdir(parents=True, exist_ok=True)
    if dst.is_file() and os.path.samefile(src, dst):   # linked already (rename would leave the temporary)
        return
    tmp = dst.with_name(f"{dst.name}.{os.getpid()}.tmp")
    if tmp.exists() or tmp.is_symlink():
        tmp.unlink()
    try:
        os.link(src, tmp)
    except OSError:
        shutil.copy2(src, tmp)
    os.replace(tmp, dst)


def copy(src: Path, dst: Path, *, hard_link: bool = False) -> None:
    """Replace ``dst`` with a copy of ``src`` (a file or a folder; ``hard_link``: a file linked)."""
    if dst.is_dir() and not dst.is_symlink():
        shutil.rmtree(dst)
    elif dst.exists():
        dst.unlink()
    dst.parent.mkdir(parents=True, exist_ok=True)
    if src.is_dir():
        shutil.copytree(src, dst)
    elif hard_link:
        link(src, dst)
    else:
        shutil.copy2(src, dst)
