"""Plugin: which tests share a pytest-xdist worker (groups) and the order the groups are queued in."""
import pytest

# The default tier runs on two pytest-xdist workers (pyproject addopts: -n 2 --dist loadgroup).
# A worker keeps its compiled functions, so tests that fly the same shapes or share session
# fixtures run in one worker (a group); every other file is a group of its own. Groups are
# queued longest first (measured CPU time), so the two workers finish together.
XDIST_GROUPS = {
    # the 2 s / 1.5 s policy flights, decoders and the released policy's recording, then the
    # notebooks, whose cells run in-process and fly those shapes again
    "policy-flights": ("test_api", "test_decode", "test_envs", "test_interface", "test_notebooks", "test_replay"),
    # the tiny Trainer, and the collect run of conftest.collected_pairs
    "policy-training": ("test_policy", "test_sequence"),
    # conftest.exact_model_posteriors: one exact-model log's SMC, NUTS and longer NUTS run, read by both
    "exact-model": ("test_nuts", "test_sampler_reference"),
    # the calibration's flights: 2 vehicles a set, one program per motor map
    "calibration": ("test_calibrate", "test_calibration_stage"),
}
_GROUP_OF = {f: g for g, files in XDIST_GROUPS.items() for f in files}
# Queue order, longest first (seconds of the default tier, `pytest --durations=0`, 2026-11-30), so
# that the short files come last and fill in; files not listed after them. (A long file not listed
# runs last: test_identify, 27 s, once kept one worker going 23 s after the other had finished.)
_QUEUE = ("policy-training", "policy-flights", "test_identify", "calibration", "test_control", "exact-model",
          "test_experiments_robustness", "test_tune", "test_cfm", "test_sim", "test_speeds",
          "test_idlecheck", "test_docs_generated", "test_distributed", "test_resume", "test_logcheck", "test_render",
          "test_references", "test_export", "test_theta", "test_mujoco_sysid",
          "test_vibration", "test_heldout", "test_log_holes", "test_motor_map", "test_windowcheck", "test_focus",
          "test_logspace", "test_train_options", "test_sensor_randomization", "test_inputs", "test_probe_loop",
          "test_architecture")


def pytest_configure(config):
    config.addinivalue_line("markers", "xdist_group(name): run in the xdist worker of that group")


# tryfirst: xdist's worker adds the group to each test's id in its own collection hook, which
# must see these markers (without it, every test was scheduled on its own and groups split).
@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config, items):
    rank = {g: i for i, g in enumerate(_QUEUE)}
    for item in items:
        stem = item.path.stem
        item.add_marker(pytest.mark.xdist_group(_GROUP_OF.get(stem, stem)))
    # stable: the order of the tests within a file (and of the files within a group) is kept
    items.sort(key=lambda it: rank.get(_GROUP_OF.get(it.path.stem, it.path.stem), len(rank)))
