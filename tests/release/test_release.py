"""`mjxsysid release`: the stage plan, resuming, the release.json record and the CLI's errors, on
stub stages (default tier, no JAX work); the tiny end-to-end release on the CPU (slow)."""
import dataclasses
import json
import shutil
from pathlib import Path

import pytest

from mjxsysid.cli import main
from mjxsysid.release import Release
from mjxsysid.release.layout import link
from mjxsysid.release.provenance import call
from mjxsysid.release.stages import STAGES, Stage, StageResult
from mjxsysid.release.stages.ship import build_tree
from support.paths import ROOT



def _stubs(calls, fail=()):
    """A four-stage release: a -> b -> c, and ship; each writes its output and counts its calls."""
    def make(name):
        def run(rel, out):
            calls.append(name)
            if name in fail:
                raise RuntimeError(f"{name} broke")
            (out / f"{name}.txt").write_text(name)
            return StageResult(calls=(call(make, name=name),), config={"n": 1}, figures={"value": len(calls)})
        return run
    return (Stage("a", make("a"), (), ("a.txt",), 10, "first"),
            Stage("b", make("b"), ("a",), ("b.txt",), 20, "second"),
            Stage("c", make("c"), ("b",), ("c.txt",), 30, "third"),
            Stage("ship", make("ship"), (), ("ship.txt",), 1, "ship"))


def _release(out, calls, options=None, **kw):
    return Release(out, options, stages=_stubs(calls, **kw), log=None, device=lambda: "stub device",
                   commit=lambda: "abc123")


def test_stages_run_in_order_and_resume_skips_done_ones(tmp_path):
    calls = []
    assert _release(tmp_path, calls).run(["a,b"]) == ["a", "b"]
    assert calls == ["a", "b"]
    assert _release(tmp_path, calls).run() == ["c", "ship"]       # a and b are done: skipped
    assert _release(tmp_path, calls).run() == []
    assert calls == ["a", "b", "c", "ship"]
    # a stage whose output is gone runs again; forcing a stage reruns it and what depends on it
    (tmp_path / "c" / "c.txt").unlink()
    rel = _release(tmp_path, calls)
    assert rel.status("c") == "incomplete"
    assert rel.run() == ["c"]
    assert _release(tmp_path, calls).run(force=["b"]) == ["b", "c"]
    assert _release(tmp_path, calls).run(["a"], force=["a"]) == ["a"]
    rel = _release(tmp_path, calls)
    assert rel.status("b") == "stale" and rel.status("a") == "done"   # b ran before a's rerun
    assert rel.status("c") == "done"                                  # b itself has not run again
    assert rel.run(["b", "c"]) == ["b", "c"]
    # ship needs nothing, but a later run of a stage it comes ``after`` makes it stale
    stubs = list(_stubs(calls))
    stubs[3] = Stage("ship", stubs[3].run, (), ("ship.txt",), 1, "ship", after=("c",))
    rel = Release(tmp_path, stages=stubs, log=None, device=lambda: "d", commit=lambda: "x")
    assert rel.status("ship") == "stale" and rel.run(["ship"]) == ["ship"]
    assert Release(tmp_path, stages=stubs, log=None).status("ship") == "done"


def _fork_stubs(calls, hook=None):
    """a -> (b, c) -> ship: b and c need only a, so two processes may run them at once; ``hook``
    runs inside b (to interleave another release object there)."""
    def make(name):
        def run(rel, out):
            calls.append(name)
            if name == "b" and hook:
                hook()
            (out / f"{name}.txt").write_text(name)
            return StageResult(figures={"value": name})
        return run
    return (Stage("a", make("a"), (), ("a.txt",), 10, "first"),
            Stage("b", make("b"), ("a",), ("b.txt",), 20, "one branch"),
            Stage("c", make("c"), ("a",), ("c.txt",), 30, "the other"),
            Stage("ship", make("ship"), (), ("ship.txt",), 1, "ship"))


def test_stages_of_one_release_run_by_two_processes_at_once_keep_both_records(tmp_path):
    """Two Release objects (as two processes, one per GPU) run b and c of one folder while the
    other is mid-stage: the record keeps both entries and distinct run numbers, and the linked
    files of one folder can be made by both."""
    calls = []
    Release(tmp_path, stages=_fork_stubs(calls), log=None, device=lambda: "d", commit=lambda: "x").run(["a"])
    other = Release(tmp_path, stages=_fork_stubs(calls), log=None, device=lambda: "d", commit=lambda: "x")
    first = Release(tmp_path, stages=_fork_stubs(calls, hook=lambda: other.run(["c"])), log=None,
                    device=lambda: "d", commit=lambda: "x")
    assert first.run(["b"]) == ["b"]        # c ran (in `other`) while b was running
    rec = json.loads((tmp_path / "release.json").read_text())
    assert {k: v["status"] for k, v in rec["stages"].items()} == {"a": "done", "b": "done", "c": "done"}
    runs = sorted(v["run"] for v in rec["stages"].values())
    assert runs == [1, 2, 3] and rec["runs"] == 3
    assert rec["stages"]["b"]["run"] == 2 and rec["stages"]["c"]["run"] == 3
    fresh = Release(tmp_path, stages=_fork_stubs(calls), log=None, device=lambda: "d", commit=lambda: "x")
    assert [fresh.status(n) for n in "abc"] == ["done"] * 3
    src = tmp_path / "a" / "a.txt"
    link(src, tmp_path / "set" / "a.txt")
    link(src, tmp_path / "set" / "a.txt")     # replacing an existing link
    assert (tmp_path / "set" / "a.txt").read_text() == "a" and sorted(p.name for p in (tmp_path / "set").iterdir()) == ["a.txt"]


def test_release_json_records_each_stage(tmp_path):
    calls = []
    _release(tmp_path, calls, options={"scale": "tiny"}).run(["a"])
    with pytest.raises(RuntimeError, match="b broke"):
        _release(tmp_path, calls, fail=("b",)).run(["b"])
    rec = json.loads((tmp_path / "release.json").read_text())
    assert rec["release"] == tmp_path.name and rec["order"] == ["a", "b", "c", "ship"]
    assert rec["options"] == {"scale": "tiny", "policy_config": None, "from_policy": None}
    a, b = rec["stages"]["a"], rec["stages"]["b"]
    assert a["calls"] == [{"call": f"{__name__}._stubs.<locals>.make", "args": {"name": "a"}}]
    assert a["status"] == "done" and a["config"] == {"n": 1}
    assert a["figures"] == {"value": 1} and a["outputs"] == ["a.txt"]
    assert a["commit"] == "abc123" and a["device"] == "stub device" and a["wall_s"] >= 0
    assert a["started"] <= a["ended"] and a["attempts"] == 1 and a["run"] == 1 and b["run"] == 2
    assert b["status"] == "failed" and b["error"] == "RuntimeError: b broke" and "traceback" in b
    rel = _release(tmp_path, calls)
    assert rel.status("b") == "failed" and rel.status("c") == "pending"
    assert rel.run(["b"]) == ["b"] and rel.entry("b")["attempts"] == 2 and "error" not in rel.entry("b")
    table = rel.table()
    assert "a " in table and "done" in table and "pending" in table and "H100" in table


def test_plan_errors_name_the_stage(tmp_path):
    rel = _release(tmp_path, [])
    with pytest.raises(ValueError, match="unknown stage 'x'; stages: a, b, c, ship"):
        rel.plan(["a,x"])
    with pytest.raises(ValueError, match="--force: unknown stage 'y'"):
        rel.plan(force=["y"])
    with pytest.raises(ValueError, match="stage 'c' needs stage 'b', which is pending"):
        rel.plan(["c"])
    assert rel.plan(["b,a"]) == ["a", "b"]                               # release order, not the given one
    with pytest.raises(ValueError, match=r"cannot ship: stage\(s\) a, b, c not done"):
        rel.plan(["ship"])
    assert rel.plan(["ship"], allow_partial=True) == ["ship"]
    with pytest.raises(ValueError, match="--allow-partial applies to an explicit --stages ship"):
        rel.plan(allow_partial=True)
    assert rel.plan() == ["a", "b", "c", "ship"]                        # all in one call: ship last


def test_recorded_options_may_not_change(tmp_path):
    _release(tmp_path, [], options={"scale": "tiny"}).run(["a"])
    assert _release(tmp_path, []).options.scale == "tiny"               # resumed with the recorded ones
    with pytest.raises(ValueError, match="started with scale = 'tiny', not 'full'"):
        _release(tmp_path, [], options={"scale": "full"})
    with pytest.raises(ValueError, match="scale must be one of"):
        _release(tmp_path / "new", [], options={"scale": "huge"})
    (tmp_path / "file").write_text("x")
    with pytest.raises(ValueError, match="is a file, not a release folder"):
        _release(tmp_path / "file", [])


def test_stage_list_is_the_pipeline():
    names = [s.name for s in STAGES]
    from mjxsysid.cli.release import STAGE_NAMES
    assert tuple(names) == STAGE_NAMES == STAGES.names()
    assert names.index("posterior_calibration") < names.index("tables") < names.index("ship")
    for i, s in enumerate(STAGES):                                      # dependencies come earlier
        assert all(names.index(d) < i for d in s.needs), s.name
        if s.name != "posterior_calibration":                           # resumes by piece (below)
            assert 0 < s.estimate_s <= 600, s.name                      # each fits a 10-minute GPU call
    assert sum(s.estimate_s for s in STAGES if s.name != "posterior_calibration") <= 45 * 60
    # the calibration's ≈ 8,200 logs at 1.1 logs/s: hours, in pieces that fit a call or resume over several
    from mjxsysid.release.sizes import FULL_CALIBRATION as cal
    from mjxsysid.release.stages.calibration import LOGS_PER_S, pieces
    est = STAGES["posterior_calibration"].estimate_s
    assert cal.logs() == (5120, 1792, 1280) and est == sum(cal.logs()) / LOGS_PER_S
    one_flight = [s.logs(len(lv)) / cal.shards for _, _, s, lv, _, _ in pieces(cal) if len(s.flights) == 1]
    assert one_flight and all(n / LOGS_PER_S <= 480 for n in one_flight)     # within a call, flying besides


def _cli(capsys, *args):
    rc = main(["release", *map(str, args)])
    out = capsys.readouterr()
    return rc, out.out, out.err


def test_cli_errors_are_one_line(tmp_path, capsys):
    for args, msg in (((tmp_path / "r", "--stages", "policy,bogus"), "unknown stage 'bogus'"),
                      ((tmp_path / "r", "--stages", "decoders"), "stage 'decoders' needs stage 'pairs'"),
                      ((tmp_path / "r", "--policy-config", tmp_path / "none.json"), "config file not found"),
                      ((tmp_path / "r", "--from-policy", tmp_path / "none.npz"), "policy weights not found"),
                      ((tmp_path / "r", "--list"), "no release in"),
                      ((tmp_path / "r", "--stages", "ship"), "cannot ship"),
                      ((tmp_path / "r",), "give its root (--docs-root"),
                      ((tmp_path / "r", "--stages", "ship", "--allow-partial"), "give its root (--ship-to")):
        rc, out, err = _cli(capsys, "--out", *args)
        assert rc == 2 and msg in err and len(err.strip().splitlines()) == 1, (args, err)
    (tmp_path / "f").write_text("x")
    rc, _, err = _cli(capsys, "--out", tmp_path / "f", "--list")
    assert rc == 2 and "is a file, not a release folder" in err
    assert not (tmp_path / "r").exists()                                # nothing written by a refused call


def test_cli_list_shows_recorded_stages(tmp_path, capsys):
    rel = Release(tmp_path, {"scale": "tiny"}, log=None)
    rel.record["stages"]["policy"] = {"status": "done", "started": "2026-01-01T00:00:00+00:00",
                                      "ended": "2026-01-01T00:02:00+00:00", "wall_s": 120.0}
    (tmp_path / "policy").mkdir()
    (tmp_path / "policy" / "policy.npz").write_bytes(b"")
    rel.save()
    rc, out, _ = _cli(capsys, "--out", tmp_path, "--list")
    assert rc == 0
    lines = {ln.split()[0]: ln for ln in out.splitlines()[2:-1]}
    assert list(lines) == [s.name for s in STAGES]
    assert "done" in lines["policy"] and "120 s" in lines["policy"] and "2026-01-01T00:02:00" in lines["policy"]
    assert "pending" in lines["pairs"] and "(tiny;" in out


def test_ship_tree_carries_release_provenance(tmp_path):
    """build_tree on stage folders holding the shipped weights: each provenance JSON says which
    release, stage, commit and device made it; --allow-partial leaves out what is missing."""
    pre = ROOT / "mjxsysid" / "pretrained"
    rel = Release(tmp_path / "rel", {"scale": "tiny"}, log=None, device=lambda: "dev", commit=lambda: "c0ffee")
    for stage, f in (("policy", "policy.npz"), ("decoders", "cfm.npz"), ("decoders", "regression.npz")):
        (rel.stage_dir(stage)).mkdir(parents=True, exist_ok=True)
        shutil.copy(pre / f, rel.stage_dir(stage) / f)
    (rel.stage_dir("policy_eval")).mkdir()
    (rel.stage_dir("policy_eval") / "eval.json").write_text(json.dumps({"n": 10}))
    (rel.stage_dir("policy_eval") / "heldout").mkdir()
    (rel.stage_dir("policy_eval") / "heldout" / "results.json").write_text("{}")
    for name in ("policy", "pairs", "decoders", "policy_eval"):
        rel.record["stages"][name] = {"status": "done", "started": "2026-01-01T00:00:00+00:00",
                                      "ended": "2026-01-01T00:01:00+00:00", "wall_s": 60.0, "commit": "c0ffee",
                                      "device": "dev", "calls": [{"call": f"stage {name}", "args": {}}]}
    with pytest.raises(FileNotFoundError, match="not written"):
        build_tree(rel, tmp_path / "tree")
    left = build_tree(rel, tmp_path / "tree", partial=True)
    assert "seq_decoder/cfm_seq.npz" in left and "noise/noise_sensitivity.json" in left
    tree = tmp_path / "tree"
    pol = json.loads((tree / "mjxsysid/pretrained/policy.json").read_text())
    assert pol["release"] == {"dir": "rel", "path": str(rel.out.resolve()), "commit": "c0ffee", "stage": "policy",
                              "stage_wall_s": 60.0, "stage_ended": "2026-01-01T00:01:00+00:00", "device": "dev",
                              "scale": "tiny"}
    assert pol["evaluation"] == {"n": 10} and pol["config"]["num_envs"] > 0
    cfm = json.loads((tree / "mjxsysid/pretrained/cfm.json").read_text())
    assert cfm["release"]["stage"] == "decoders" and cfm["data"]["pairs_sha256"]
    assert cfm["calls"] == [{"call": "stage decoders", "args": {}}] and pol["calls"][0]["call"] == "stage policy"
    assert pol["command"] == "mjxsysid release --out rel"
    assert (tree / "docs/runs/release/policy/eval.json").is_file()
    assert not (tree / "mjxsysid/pretrained/cfm_seq.json").exists()
    # a release that adopted a policy keeps how it was trained (command, commit) from the JSON beside it
    shipped = json.loads((pre / "policy.json").read_text())
    shutil.copy(pre / "policy.json", rel.stage_dir("policy") / "adopted_policy.json")   # as the stage keeps it
    rel.options = dataclasses.replace(rel.options, from_policy=str(pre / "policy.npz"))
    build_tree(rel, tmp_path / "tree2", partial=True)
    pol = json.loads((tmp_path / "tree2/mjxsysid/pretrained/policy.json").read_text())
    assert pol["command"] == shipped["command"] and pol["commit"] == shipped["commit"]
    assert pol["adopted_from"] == str(pre / "policy.npz") and pol["release"]["commit"] == "c0ffee"


@pytest.mark.slow
def test_tiny_release_end_to_end(tmp_path, capsys):
    """Every stage at CPU size through the CLI (minutes of compiles): the record, the shipped tree
    (weights + provenance tied to the release, docs run files, regenerated pages), then a re-run
    that has nothing to do."""
    out = tmp_path / "rel"
    rc, stdout, _ = _cli(capsys, "--out", out, "--tiny", "--docs-root", ROOT, "-q")
    assert rc == 0, stdout
    rec = json.loads((out / "release.json").read_text())
    assert [rec["stages"][s.name]["status"] for s in STAGES] == ["done"] * len(STAGES)
    ship = out / "ship"
    for f in ("policy", "cfm", "regression", "cfm_seq"):
        prov = json.loads((ship / "mjxsysid/pretrained" / f"{f}.json").read_text())
        assert prov["release"]["dir"] == "rel" and prov["release"]["scale"] == "tiny"
        assert (ship / "mjxsysid/pretrained" / f"{f}.npz").is_file()
    assert "Fair comparisons" in (ship / "docs/fair_comparisons.md").read_text()
    assert (ship / "docs/runs/release/tuning/tune_slow/results.json").is_file()
    assert (ship / "docs/runs/release/decoders/seq_decoder_eval.json").is_file()
    assert rec["stages"]["pairs"]["config"]["imu"]["randomize_imu"] is True      # the release config's IMU
    table = json.loads((ship / "mjxsysid/pretrained/posterior_calibration.json").read_text())
    assert table["provenance"]["release"]["dir"] == "rel" and table["provenance"]["rows"] > 0
    assert (ship / "docs/runs/release/calibration/evaluation.json").is_file()
    rc, _, err = _cli(capsys, "--out", out, "-q")
    assert rc == 0 and "stages run" not in err
    assert json.loads((out / "release.json").read_text())["runs"] == rec["runs"]    # nothing ran again


def test_ship_replaces_docs_runs_release_whole(tmp_path):
    """`ship` removes the previous release's docs/runs/release/ before copying the new tree (no file
    of an earlier release stays) and ships the record beside the run files."""
    from mjxsysid.release.stages.ship import ship
    stages = (Stage("tables", lambda r, o: StageResult(), (), (), 1, "lay out"),
              Stage("ship", ship, ("tables",), (), 1, "ship"))
    rel = Release(tmp_path / "rel", {"scale": "tiny"}, ship_to=tmp_path / "dest", stages=stages, log=None,
                  device=lambda: "dev", commit=lambda: "c0ffee")
    rel.record["stages"]["tables"] = {"status": "done"}
    rel.out.mkdir(parents=True, exist_ok=True)
    (rel.out / "release.json").write_text(json.dumps(rel.record))
    new = rel.stage_dir("tables") / "tree" / "docs" / "runs" / "release" / "policy" / "eval.json"
    new.parent.mkdir(parents=True)
    new.write_text("{}")
    stale = tmp_path / "dest" / "docs" / "runs" / "release" / "old_kind" / "results.json"
    stale.parent.mkdir(parents=True)
    stale.write_text("{}")
    kept = tmp_path / "dest" / "docs" / "runs" / "measurements" / "x" / "results.json"
    kept.parent.mkdir(parents=True)
    kept.write_text("{}")
    (rel.stage_dir("ship")).mkdir(parents=True)
    ship(rel, rel.stage_dir("ship"))
    runs = tmp_path / "dest" / "docs" / "runs"
    assert not stale.exists() and kept.is_file()
    assert (runs / "release" / "policy" / "eval.json").is_file()
    assert json.loads((runs / "release" / "release.json").read_text())["stages"]["tables"]["status"] == "done"


def test_release_config_is_package_data_and_sizes_are_frozen():
    """The default policy config ships inside the package (a wheel runs a release without a
    checkout); the sizes cannot be changed by a stage."""
    import mjxsysid
    from mjxsysid.release.sizes import FULL, TINY
    from mjxsysid.release.stages.policy import DEFAULT_POLICY_CONFIG, config_path
    assert DEFAULT_POLICY_CONFIG.is_file() and Path(mjxsysid.__file__).parent in DEFAULT_POLICY_CONFIG.parents
    assert config_path(None) == DEFAULT_POLICY_CONFIG and config_path("x.json") == Path("x.json")
    with pytest.raises(dataclasses.FrozenInstanceError):
        TINY.eval_vehicles = 1
    with pytest.raises(TypeError):
        TINY.cfm["epochs"] = 1
    assert FULL.train == {} and TINY.train["iterations"] == 4 and set(TINY.noise.levels) == set(FULL.noise.levels)


def test_pages_read_a_release_tree_over_the_checkout(tmp_path):
    """A generated page is a function of the checkout's run files with a release's tree laid over
    them: no tree gives the checkout's page; a run file in the tree replaces the checkout's."""
    from mjxsysid.release.layout import run_path
    from mjxsysid.release.pages import check, noise
    assert check(ROOT) == []
    assert noise.page(ROOT) == (ROOT / noise.PAGE).read_text() == noise.page(ROOT, overlay=tmp_path)
    rel = run_path("noise", "noise_sensitivity.json")
    res = json.loads((ROOT / rel).read_text())
    for v in res["levels"].values():
        v["pos_rmse_m"]["median"] += 0.5
    (tmp_path / rel).parent.mkdir(parents=True)
    (tmp_path / rel).write_text(json.dumps(res))
    page = noise.page(ROOT, overlay=tmp_path)
    assert page != (ROOT / noise.PAGE).read_text() and page.count("\n") == (ROOT / noise.PAGE).read_text().count("\n")
    with pytest.raises(FileNotFoundError, match="missing run file"):
        noise.page(_bare_checkout(tmp_path))


def _bare_checkout(tmp_path):
    """A checkout with docs/noise.md but none of the run files it quotes."""
    root = tmp_path / "bare"
    (root / "docs").mkdir(parents=True)
    shutil.copy(ROOT / "docs" / "noise.md", root / "docs" / "noise.md")
    return root
