"""Several logs at once (decoding/fleet.py): the logs a folder names, the fleet table."""
from __future__ import annotations

import pytest

from mjxsysid.decoding.fleet import expand_logs, fleet_markdown, fleet_row


def test_a_folder_names_its_logs_and_a_ros2_bag_folder_is_one(tmp_path):
    (tmp_path / "a.csv").write_text("x")
    (tmp_path / "b.ulg").write_text("x")
    (tmp_path / "fleet.md").write_text("x")               # the project's own outputs are not logs
    (tmp_path / ".hidden").write_text("x")
    bag = tmp_path / "bag"
    bag.mkdir()
    (bag / "metadata.yaml").write_text("x")
    assert [p.name for p in expand_logs([tmp_path])] == ["a.csv", "b.ulg"]
    assert expand_logs([bag]) == [bag]
    with pytest.raises(FileNotFoundError, match="not found"):
        expand_logs([tmp_path / "none.csv"])
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "a.bin").write_text("x")
    with pytest.raises(ValueError, match="several logs named"):
        expand_logs([tmp_path, tmp_path / "sub"])


def test_the_fleet_table_shows_what_each_log_saw_and_why_one_was_refused():
    seen = {"log_median": 2.0, "log_q05": 1.9, "log_q95": 2.1, "seen_by_log": True, "seen_why": "ok"}
    unseen = {"log_median": 0.02, "log_q05": 0.003, "log_q95": 0.2, "seen_by_log": False, "seen_why": "slow motors"}
    summary = {"_posterior": "log-grounded",
               "_log_grounded": {"gap": {"thrust_to_weight": seen, "motor_time_constant": unseen}}}
    rows = [fleet_row("a.ulg", summary), fleet_row("b.bin", None, "never armed: log a flight"),
            fleet_row("c.csv", {"_posterior": "decoder-only"})]
    md = fleet_markdown(rows)
    line_a = next(ln for ln in md.splitlines() if ln.startswith("| a.ulg"))
    assert "2 (1.9–2.1)" in line_a and "| – |" in line_a and "1 of 2" in line_a
    assert "refused: never armed" in md and "| c.csv |" in md and "decoder-only |" in md
    assert "2 (1.9–2.1) |" in line_a                                   # not widened: no mark
    from mjxsysid.identify.idlecheck import BLIND_WHY, WIDENED
    widened = dict(seen, seen_why=f"calibrated band 0.1 of the prior's range, the motor-map check flagged the log; "
                                  f"its edges moved by -0.1 and +0 (log units) {WIDENED} (the motor-map check)")
    blind = dict(seen, seen_why="calibrated band 0.1 of the prior's range, model check passed; " + BLIND_WHY)
    md_blind = fleet_markdown([fleet_row("e.ulg", summary | {"_log_grounded": {"gap": {"thrust_to_weight": blind}}})])
    assert "2 (1.9–2.1) |" in md_blind                                  # a blind check widens nothing: no mark
    md = fleet_markdown([fleet_row("d.bin", summary | {"_log_grounded": {"gap": {"thrust_to_weight": widened}}})])
    assert "2 (1.9–2.1)* |" in md and "'*': widened" in md


def test_the_truth_headline_counts_only_what_the_log_saw():
    from mjxsysid.decoding.command import truth_headline
    gap = {"thrust_to_weight": {"seen_by_log": True, "log_inside": True},
           "motor_time_constant": {"seen_by_log": True, "log_inside": False},
           "authority_total[0]": {"seen_by_log": False, "log_inside": True}}
    line = truth_headline({"_log_grounded": {"gap": gap}}, "flight")
    assert "1/2 quantities the log saw" in line and "1 not seen" in line


def test_flights_of_one_vehicle_whose_bands_exclude_each_other_are_named():
    from mjxsysid.decoding.fleet import disagreements, disagreements_markdown

    def q(lo, hi, seen=True):
        return {"log_median": (lo + hi) / 2, "log_q05": lo, "log_q95": hi, "seen_by_log": seen}

    def row(name, tau, ax, tw):
        return fleet_row(name, {"_log_grounded": {"gap": {"motor_time_constant": tau, "authority_total[0]": ax,
                                                          "thrust_to_weight": tw}}})
    rows = [row("log10", q(0.015, 0.032), q(71, 125), q(1.41, 1.87)),        # Crazyflie's three flights
            row("log15", q(0.053, 0.070), q(341, 420), q(1.34, 1.66)),
            row("log16", q(0.012, 0.030), q(54, 106, seen=False), q(1.40, 2.0)),
            fleet_row("bench", None, "never armed")]
    found = disagreements(rows)
    pairs = {(d["quantity"], d["logs"]) for d in found}
    assert pairs == {("motor_time_constant", ("log10", "log15")), ("motor_time_constant", ("log15", "log16")),
                     ("authority_total[0]", ("log10", "log15"))}                # log16's A_x unseen; T/W overlaps
    md = disagreements_markdown(found)
    assert "3 pairs of bands exclude each other" in md and "log10 15–32 against log15 53–70" in md
    assert "overlapping" in disagreements_markdown([])


def test_a_pair_moved_to_different_motor_maps_says_so():
    """Two flights whose thrust-to-weight bands the motor-map check moved to different maps: the pair's line
    names both maps; a quantity the map does not act on, or a pair on one map, adds nothing."""
    from mjxsysid.decoding.fleet import disagreements, disagreements_markdown

    def row(name, tw, tau, m):
        return fleet_row(name, _flagged_summary(tw, [m], tau))
    a = row("log15", (1.56, 1.88), (0.01, 0.02), [0.1, 1.5])
    b = row("log16", (1.95, 2.48), (0.03, 0.04), [0.1, 2.0])
    assert a["motor_map"] == "idle +0.10 Ω_max, κ 1.5 (curved)"
    md = disagreements_markdown(disagreements([a, b]))
    tw = next(ln for ln in md.splitlines() if ln.startswith("- **T/W**"))
    tau = next(ln for ln in md.splitlines() if ln.startswith("- **τ_m"))
    assert "κ 1.5 (curved) against idle +0.10 Ω_max, κ 2" in tw and "maps differ" not in tau
    same = row("log17", (2.6, 2.9), (0.01, 0.02), [0.1, 1.5])
    assert "maps differ" not in disagreements_markdown(disagreements([a, same]))
    assert fleet_row("x", {"_log_grounded": {"gap": {}}})["motor_map"] is None


def _flagged_summary(tw, maps, tau=None):
    """A summary.json of a log the motor-map check flagged: thrust-to-weight's band ``tw`` (and τ_m's ``tau``),
    the best map first of ``maps``, all of them plausible."""
    def band(b):
        return {"log_median": sum(b) / 2, "log_q05": b[0], "log_q95": b[1], "seen_by_log": True}
    cal = {"model_check": {"idle": {"ok": False}}, "features": {"idle_map": maps[0], "idle_plausible": maps}}
    gap = {"thrust_to_weight": band(tw)} | ({"motor_time_constant": band(tau)} if tau else {})
    return {"_log_grounded": {"gap": gap, "calibration": cal}, "_posterior": "log-grounded"}


def test_flights_of_one_vehicle_share_the_motor_maps_they_showed():
    """``--same-vehicle``: the maps any flagged flight's bands hold are the vehicle's, in MAPS's order; a flagged
    flight lacking one is decoded again with them; a flight the check passed has no maps and is not."""
    from mjxsysid.decoding.fleet import lacks_shared, shared_maps, shared_maps_markdown
    a = fleet_row("log15", _flagged_summary((1.56, 1.91), [[0.1, 1.5], [0.0, 1.5]]))
    b = fleet_row("log16", _flagged_summary((1.97, 2.48), [[0.1, 2.0]]))
    passed = fleet_row("log10", {"_log_grounded": {"gap": {}, "calibration": {"model_check": {"idle": {"ok": True}},
                                                                              "features": {"idle_plausible": []}}}})
    maps = shared_maps([a, b, passed, {"log": "x", "error": "refused"}])
    assert maps == ((0.0, 1.5), (0.1, 1.5), (0.1, 2.0))
    assert lacks_shared(a, maps) and lacks_shared(b, maps) and not lacks_shared(passed, maps)
    assert not lacks_shared(a, ((0.1, 1.5),)) and shared_maps([passed]) == ()
    md = shared_maps_markdown(maps, ["log16.bin"])
    assert "κ 2 (curved)" in md and "log16.bin" in md and shared_maps_markdown((), []) == ""


def test_same_vehicle_decodes_a_flagged_flight_again_with_the_vehicles_maps(tmp_path, monkeypatch):
    """The CLI's two passes (nothing decoded: run_decode faked): each log once, then each flagged flight whose
    maps lack another flight's again with all of them; fleet.md says which, and the pair that excluded each
    other under their own maps overlaps."""
    import json
    import mjxsysid.decoding as D
    from mjxsysid.cli import main
    calls = []
    own = {"log15": [[0.1, 1.5]], "log16": [[0.1, 2.0]]}
    bands = {"log15": (1.56, 1.91), "log16": (1.97, 2.48)}

    def fake_run_decode(out, *, log, shared_maps=None, **kw):
        calls.append((log.stem, shared_maps))
        maps = own[log.stem] + [list(m) for m in shared_maps or () if list(m) not in own[log.stem]]
        lo, hi = bands[log.stem]
        if shared_maps:
            lo, hi = min(lo, 1.67), max(hi, 1.99)        # the band holds the values under the other map too
        return _flagged_summary((lo, hi), maps)
    monkeypatch.setattr(D, "run_decode", fake_run_decode)
    logs = []
    for n in own:
        (tmp_path / f"{n}.bin").write_bytes(b"x")
        logs.append(str(tmp_path / f"{n}.bin"))
    out = tmp_path / "o"
    assert main(["decode", "--log", *logs, "--same-vehicle", "--out", str(out)]) == 0
    assert calls[:2] == [("log15", None), ("log16", None)]
    assert sorted(c[0] for c in calls[2:]) == ["log15", "log16"]
    assert all(c[1] == ((0.1, 1.5), (0.1, 2.0)) for c in calls[2:])
    md = (out / "fleet.md").read_text()
    assert "Decoded again with them: log15.bin, log16.bin" in md and "overlapping 90 % bands" in md
    assert json.loads((out / "fleet.json").read_text())[1]["maps"] == [[0.1, 2.0], [0.1, 1.5]]
    calls.clear()
    assert main(["decode", "--log", *logs, "--out", str(tmp_path / "p")]) == 0       # not one vehicle: one pass
    assert [c[1] for c in calls] == [None, None]
