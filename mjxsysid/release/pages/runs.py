"""Reading the run files a generated page quotes: from a checkout, or from a release's tree laid
over it."""
from __future__ import annotations

import json
from pathlib import Path


class RunFiles:
    """The run files of the checkout at ``root``; ``overlay``: a tree laid out like the checkout
    whose files take precedence where it has them (a release's, before it ships)."""

    def __init__(self, root, overlay=None):
        self.root = Path(root)
        self.overlay = None if overlay is None else Path(overlay)

    def path(self, rel: str) -> Path:
        """Where the run file ``rel`` (a path relative to the checkout's root) is read from."""
        if self.overlay is not None and (self.overlay / rel).is_file():
            return self.overlay / rel
        return self.root / rel

    def load(self, rel: str) -> dict:
        """The JSON of the run file ``rel``; a missing one is a FileNotFoundError naming it."""
        path = self.path(rel)
        if not path.is_file():
            raise FileNotFoundError(f"missing run file {path} (run the measurement that writes it, or "
                                    f"`mjxsysid release`)")
        return json.loads(path.read_text())
