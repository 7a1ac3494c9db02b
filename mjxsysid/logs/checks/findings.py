"""What a log check returns: a :class:`Finding` each, raised together as a :class:`LogError`."""
from __future__ import annotations

import dataclasses


@dataclasses.dataclass(frozen=True)
class Finding:
    """One result of a check: ``level`` 'error' (the log cannot be right), 'warning' (suspicious)
    or 'out_of_prior' (the decoders were not trained on such a vehicle); ``column`` the log
    column(s) concerned; ``message`` what was found, the likely cause and the fix."""
    level: str
    column: str
    message: str

    def __str__(self) -> str:
        return f"{self.column}: {self.message}"

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)


def warn(finding) -> None:
    """Print a finding on stderr: always, whatever ``--quiet`` says (as errors are)."""
    import sys
    label = "out of prior" if getattr(finding, "level", "") == "out_of_prior" else "warning"
    print(f"{label}: {finding}", file=sys.stderr, flush=True)


class LogError(ValueError):
    """A log that cannot be right: ``findings`` holds every finding (errors and warnings)."""

    def __init__(self, path, findings):
        self.findings = list(findings)
        errs = [f for f in self.findings if f.level == "error"]
        super().__init__(f"{path}: " + "; ".join(str(f) for f in errs))
