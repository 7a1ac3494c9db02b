"""The shipping stages: lay out what a release ships as a tree (weights with provenance, the
docs' run files, the regenerated pages), then copy that tree into a checkout."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

from mjxsysid.runtime import jsonout
from mjxsysid.release import layout
from mjxsysid.release.provenance import call, decoder_provenance, policy_provenance
from mjxsysid.release.record import RECORD
from mjxsysid.release.stages.policy import ADOPTED_PROVENANCE
from mjxsysid.release.stages.registry import STAGES, ReleaseView, StageResult


_TRAINING_KEYS = ("command", "commit", "device", "jax", "wall_s", "env_steps", "mean_train_steps_per_s")


def _adopted_training(rel: ReleaseView) -> dict:
    """For a release that adopted a policy (``--from-policy``): how that policy was trained, from
    the provenance JSON the policy stage kept beside it (its command, commit, device, wall time,
    steps/s: the release did not train it), and where it came from. Empty for a release that
    trained its own."""
    if not rel.options.from_policy:
        return {}
    out = {"adopted_from": rel.options.from_policy}
    prov = rel.stage_dir("policy") / ADOPTED_PROVENANCE
    if prov.is_file():
        prior = json.loads(prov.read_text())
        out.update({k: prior[k] for k in _TRAINING_KEYS if k in prior})
    return out


def _json(path: Path) -> dict:
    return json.loads(path.read_text()) if path.is_file() else {}


def build_tree(rel: ReleaseView, tree: Path, *, partial: bool = False) -> list[str]:
    """Lay out what a release ships, as a tree rooted at ``tree`` (paths of
    [layout][mjxsysid.release.layout]): the weights, hard-linked, and their provenance JSON
    (each with the calls of the stage that made it and a ``release`` section: the release
    folder, commit, stage, its wall time and device), the posterior calibration table with that
    section in its own provenance, the docs' run files and figures.
    ``partial``: skip what a stage not done did not write (else an error). Returns what was left
    out."""
    left_out = []
    pre = tree / layout.PRETRAINED

    def have(stage, rel_path):
        ok = rel.done(stage) and (rel.stage_dir(stage) / rel_path).exists()
        if not ok:
            if not partial and rel_path not in layout.OPTIONAL:
                raise FileNotFoundError(f"{rel.stage_dir(stage) / rel_path}: not written (stage {stage} "
                                        f"is {rel.status(stage)})")
            left_out.append(f"{stage}/{rel_path}")
        return ok

    def release_info(stage):
        e = rel.entry(stage)
        return {"dir": rel.out.name, "path": str(rel.out.resolve()), "commit": e.get("commit"), "stage": stage,
                "stage_wall_s": e.get("wall_s"), "stage_ended": e.get("ended"), "device": e.get("device"),
                "scale": rel.options.scale}

    cmd = f"mjxsysid release --out {rel.out.name}"
    if have("policy", "policy.npz"):
        layout.copy(rel.policy_path, pre / "policy.npz", hard_link=True)
        prov = policy_provenance(rel.policy_path, _json(rel.stage_dir("policy_eval") / "eval.json"),
                                 train_log=rel.stage_dir("policy") / "train_log.jsonl", command=cmd,
                                 commit=rel.entry("policy").get("commit"))
        del prov["evaluation_command"]
        prov.update(calls=rel.entry("policy").get("calls", []),
                    evaluation_calls=rel.entry("policy_eval").get("calls", []))
        prov.update(_adopted_training(rel))
        prov["release"] = release_info("policy")
        (pre / "policy.json").write_text(jsonout.dumps(prov, indent=2, ensure_ascii=False) + "\n")
    evals = {"single": rel.stage_dir("decoder_eval") / "single" / "decoder_eval.json",
             "flight": rel.stage_dir("decoder_eval") / "flight" / "decoder_eval.json"}
    for stage, f in layout.SHIPPED[1:]:
        if not have(stage, f):
            continue
        kind = f.removesuffix(".npz")
        layout.copy(rel.stage_dir(stage) / f, pre / f, hard_link=True)
        prov = decoder_provenance(rel.stage_dir(stage) / f, kind, _json(evals["flight" if kind == "cfm_seq" else "single"]),
                                  what="of the release's policy latent", command=cmd, evaluation_command=None,
                                  commit=rel.entry(stage).get("commit"))
        prov.update(calls=rel.entry(stage).get("calls", []),
                    evaluation_calls=rel.entry("decoder_eval").get("calls", []))
        prov["release"] = release_info(stage)
        (pre / f"{kind}.json").write_text(jsonout.dumps(prov, indent=2, ensure_ascii=False) + "\n")
    for stage, f in layout.TABLES:
        if have(stage, f):
            table = _json(rel.stage_dir(stage) / f)
            prov = table.setdefault("provenance", {})
            prov.update(calls=rel.entry(stage).get("calls", prov.get("calls", [])), release=release_info(stage))
            pre.mkdir(parents=True, exist_ok=True)
            (pre / f).write_text(json.dumps(table, indent=1, ensure_ascii=False) + "\n")   # its infinities kept
    for stage, src, dst in layout.DOCS_RUNS:
        if have(stage, src):
            layout.copy(rel.stage_dir(stage) / src, tree / dst)
            layout.shrink_pngs(tree / dst)
    for stage, src, dst in layout.DOCS_FILES:
        if have(stage, src):
            layout.copy(rel.stage_dir(stage) / src, tree / dst)
    return left_out


@STAGES.add(needs=("policy_eval", "decoder_eval", "noise", "tune_nominal", "tune_slow", "tune_slow_more",
                   "tune_lemniscate", "studies", "fidelity", "posterior_calibration"),
            outputs=("tree",), estimate_s=5,
            what="lay out the shipped tree and regenerate the generated docs pages in it (pages.generate)")
def tables(rel: ReleaseView, out: Path) -> StageResult:
    """Lay out the shipped tree in out/tree (:func:`build_tree`) and regenerate the generated
    pages of ``rel.docs_root`` (a checkout) over it (:func:`mjxsysid.release.pages.generate`: each
    run file read from the tree where the release wrote one, else from the checkout), all but
    docs/runs/README.md, which describes the checkout's docs/runs/ after the ship (``ship``
    writes it). The pages quote runs a release does not make (earlier protocols, measurements):
    without a checkout (``docs_root`` None, allowed for a tiny release only, e.g. from an
    installed wheel) the tree is laid out and no page is regenerated."""
    from mjxsysid.release.pages import generate, runs_index
    if rel.docs_root is None and rel.options.scale != "tiny":
        raise ValueError("stage tables regenerates the pages of a checkout: give its root (--docs-root ROOT)")
    tree = out / "tree"
    if tree.exists():
        shutil.rmtree(tree)
    build_tree(rel, tree)
    calls, pages = [call(build_tree, tree=tree)], []
    if rel.docs_root is None:
        rel.log("[release] tables: no --docs-root: the tree is laid out, the docs pages are not regenerated")
    else:
        for path, text in generate(rel.docs_root, overlay=tree).items():
            if path != runs_index.PAGE:
                (tree / path).parent.mkdir(parents=True, exist_ok=True)
                (tree / path).write_text(text)
                pages.append(path)
        calls.append(call(generate, root=rel.docs_root, overlay=tree))
    files = sorted(str(p.relative_to(tree)) for p in tree.rglob("*") if p.is_file())
    return StageResult(calls=tuple(calls),
                       config={"tree": str(tree), "docs_root": None if rel.docs_root is None else str(rel.docs_root)},
                       figures={"files": len(files), "pages": pages})


@STAGES.add(outputs=("shipped.json",), estimate_s=5, after=("tables",),
            what="copy weights + provenance into mjxsysid/pretrained/, run files into docs/runs/release/<kind>/, the pages")
def ship(rel: ReleaseView, out: Path) -> StageResult:
    """Copy the tree of the tables stage (weights, provenance, docs run files, pages) into
    ``rel.ship_to``, replacing its docs/runs/release/ whole (with the record beside the run files).
    With ``allow_partial`` and the tables stage not done, a tree of whatever the
    done stages wrote (no pages regenerated)."""
    if rel.ship_to is None:
        raise ValueError("stage ship copies into a checkout: give its root (--ship-to ROOT)")
    tree = rel.stage_dir("tables") / "tree"
    left_out = []
    if not rel.done("tables"):
        if not rel.allow_partial:
            raise ValueError("cannot ship: stage tables not done")
        tree = out / "tree"
        if tree.exists():
            shutil.rmtree(tree)
        left_out = build_tree(rel, tree, partial=True)
    dest = rel.ship_to
    files = []
    if (tree / layout.RELEASE_RUNS).is_dir() and (dest / layout.RELEASE_RUNS).is_dir():
        shutil.rmtree(dest / layout.RELEASE_RUNS)      # replaced whole: no file of an earlier release stays
    for p in sorted(tree.rglob("*")):
        if p.is_file():
            r = p.relative_to(tree)
            layout.copy(p, dest / r)
            files.append(str(r))
    if not left_out:     # the record as the ship began, beside the run files it made
        layout.copy(rel.out / RECORD, dest / layout.RELEASE_RUNS / RECORD)
        files.append(f"{layout.RELEASE_RUNS}/{RECORD}")
    if (dest / layout.RUNS).is_dir():    # the index of docs/runs/ as the ship left it
        from mjxsysid.release.pages import runs_index
        (dest / runs_index.PAGE).write_text(runs_index.page(dest))
        files.append(runs_index.PAGE)
    (out / "shipped.json").write_text(jsonout.dumps({"to": str(dest), "files": files, "left_out": left_out},
                                                 indent=2) + "\n")
    if left_out:
        rel.log(f"[release] ship: left out (stages not done): {', '.join(left_out)}")
    rel.log(f"[release] shipped {len(files)} files into {dest}")
    return StageResult(calls=(call(layout.copy, src=tree, dst=dest),),
                       config={"to": str(dest), "partial": bool(left_out)},
                       figures={"files": len(files), "left_out": left_out})
