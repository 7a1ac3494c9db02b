"""Pages whose numbers come from run files: regenerated, never typed by hand."""
import os
import subprocess
import sys
from support.paths import ROOT



def test_fair_comparisons_page_matches_the_runs():
    """docs/fair_comparisons.md, docs/noise.md's noise tables, docs/results.md and README's results table
    are what mjxsysid.release.pages
    builds from the run files in docs/runs/ (`tools/fair_tables.py --check`: a hand edit, or a
    re-run without regenerating, fails here)."""
    # this checkout's package first (an editable install of another checkout would otherwise build the pages)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, (str(ROOT), os.environ.get("PYTHONPATH")))))
    r = subprocess.run([sys.executable, str(ROOT / "tools" / "fair_tables.py"), "--check"],
                       capture_output=True, text=True, cwd=ROOT, env=env)
    assert r.returncode == 0, r.stdout + r.stderr
    text = (ROOT / "docs" / "fair_comparisons.md").read_text()
    for heading in ("## 1. Nominal+CEM", "## 2. Action replay", "## 3. Regression", "## 5. Closed-loop",
                    "## 6a. tune-lemniscate", "## 6b. Robustness"):
        assert heading in text


def test_results_rows_come_from_the_run_files(tmp_path):
    """docs/results.md and README's results table are written from the run files: a changed figure
    in a run file changes the row (here the policy's success rate over a copy of the checkout's
    file), and a README without the generated block's markers is refused by name."""
    import json
    import shutil

    import pytest

    from mjxsysid.release.layout import run_path
    from mjxsysid.release.pages import results
    rows = results.rows(ROOT)
    assert len(rows) >= results.README_ROWS and all(r.runs for r in rows)
    rel = run_path("policy", "eval.json")
    d = json.loads((ROOT / rel).read_text())
    d["lemniscate"]["policy"]["success_rate"] = 0.5
    (tmp_path / rel).parent.mkdir(parents=True)
    (tmp_path / rel).write_text(json.dumps(d))
    row = results.rows(ROOT, overlay=tmp_path)[0]
    assert "**50 %**" in row.ours and "**missed**" in row.target
    rel = run_path("decoders", "seq_decoder_eval.json")          # a tiny release flies no paper vehicle
    d = json.loads((ROOT / rel).read_text())
    del d["sequence"]["paper_vehicle"]
    (tmp_path / rel).parent.mkdir(parents=True)
    (tmp_path / rel).write_text(json.dumps(d))
    assert "flew no paper vehicle" in results.rows(ROOT, overlay=tmp_path)[2].ours
    shutil.copy(ROOT / "README.md", tmp_path / "README.md")
    (tmp_path / "README.md").write_text((tmp_path / "README.md").read_text().replace(results.BEGIN, ""))
    with pytest.raises(ValueError, match="README.md has no generated results block"):
        results.readme(tmp_path)


def test_documentation_site_builds_strictly(tmp_path):
    """`mkdocs build --strict` (the `docs` extra, in `dev` too): every page in the nav, every
    link between pages, the API reference from the docstrings and the notebooks (rendered from
    their stored outputs, not executed) build without a warning."""
    r = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "-q", "-d", str(tmp_path / "site")],
                       capture_output=True, text=True, cwd=ROOT, env={**os.environ, "NO_MKDOCS_2_WARNING": "1"})
    assert r.returncode == 0, r.stdout + r.stderr
    site = tmp_path / "site"
    for page in ("index.html", "concepts/index.html", "envs/index.html", "reference/cfm/index.html",
                 "notebooks/00_quickstart/index.html", "benchmarks/index.html"):
        assert (site / page).is_file(), page
    assert "train_cfm" in (site / "reference/cfm/index.html").read_text()      # the reference has content


def test_probing_page_quotes_the_probe_loop_run():
    """docs/probing.md's table quotes docs/runs/measurements/probe-loop/results.json: every policy's success and
    RMSE ratio on the default and stress priors, its T/W R², and the targets met or missed."""
    import json
    r = json.loads((ROOT / "docs" / "runs" / "measurements" / "probe-loop" / "results.json").read_text())["numbers"]
    text = (ROOT / "docs" / "probing.md").read_text()
    names = {"given": "given (shipped)", "probed": "probed, round 1", "probed2": "probed, round 2",
             "probed3": "probed, round 3", "uniform": "stress-prior draws (control that knows the test)"}
    rows = {line.split("|")[1].strip(): line for line in text.splitlines() if line.startswith("| ")}
    for p, ev in r["evaluation"].items():
        row = rows[names[p]]
        for s in ("default", "stress", "stress_wide"):
            assert f"{ev[s]['rmse_ratio']:.2f}×" in row, (p, s, row)
            assert f"{100 * ev[s]['success_policy']:.1f} %".replace(".0 %", " %") in row, (p, s, row)
        assert f"{ev['latent']['r2_thrust_to_weight']:.3f}" in row, (p, row)
    assert r["final_policy"] == "probed3" and not r["targets"]["probed_beats_uniform_on_stress"]
    assert "1.34× — **missed**" in text and "1.09×" in text


def test_probing_page_quotes_the_held_out_run():
    """docs/probing.md's held-out table is the one docs/runs/measurements/held-out/probing/results.md was written with."""
    table = [line for line in (ROOT / "docs" / "runs" / "measurements" / "held-out" / "probing" / "results.md").read_text().splitlines()
             if line.startswith("|")]
    text = (ROOT / "docs" / "probing.md").read_text()
    assert len(table) >= 3 and all(line in text for line in table)
