"""A release in resumable stages: policy → decoders → every quoted experiment → posterior calibration →
docs tables → shipped files.

One command (``mjxsysid release --out DIR``): the policy, its decoders and their
calibration, every experiment whose numbers the docs quote, the log-grounded posterior's
calibration table, the generated docs pages and the shipped files, as an ordered list of named,
resumable stages.

Each stage writes into ``DIR/<stage>/`` and is recorded in ``DIR/release.json``
([record][mjxsysid.release.record]): status (done or failed), wall seconds, start and end time,
commit, device, the library calls it made with their arguments, its config and its key figures.
A stage recorded done whose declared outputs exist is skipped when the release runs again, so a
release runs in pieces (``stages=["policy"]``, then ``["pairs", "decoders"]``, …), each small
enough for one ten-minute call on a GPU; ``force`` reruns a stage from scratch. A done stage
whose dependency ran after it is *stale* (its inputs changed) and runs again
([plan][mjxsysid.release.plan]). Options that define the release (its scale, the policy's config
or the adopted policy) are recorded when it starts and may not change afterwards.

The package:

- [runner][mjxsysid.release.runner]: [Release][mjxsysid.release.runner.Release] (open, plan, run,
  list) and its [Options][mjxsysid.release.runner.Options];
- [sizes][mjxsysid.release.sizes]: what each stage runs at, ``FULL`` and ``TINY`` (CPU seconds:
  what the tests run);
- [stages][mjxsysid.release.stages]: the stages, registered in order with their needs, outputs
  and GPU time; they call the library, never a subprocess;
- [provenance][mjxsysid.release.provenance]: the record of each call, and the JSON shipped beside
  weights; [layout][mjxsysid.release.layout]: where each run kind goes in a shipped tree;
- [pages][mjxsysid.release.pages]: the generated docs pages (docs/fair_comparisons.md,
  docs/noise.md's tables).

The release reads no source checkout: its default policy config is package data, and the
checkout whose pages it regenerates (``docs_root``) and the one it ships into (``ship_to``) are
arguments. A tiny release ships into ``DIR/ship`` unless told otherwise.
"""
from mjxsysid.release.runner import Options, Release, run_release

__all__ = ["Options", "Release", "run_release"]
