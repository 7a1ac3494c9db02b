"""How scannable the Markdown pages are: sentence lengths, bullet lengths, where the first table is.

    python tools/doc_metrics.py README.md docs/status.md    # one line of figures per page
    python tools/doc_metrics.py --check                     # exit 1 if a checked page misses a target

For each page it reports the median sentence length in words, the share of sentences over 40 words,
the longest bullet in words, the line of the first table and the ``issue N`` mentions.

What counts as text: paragraphs, bullet items and block quotes. Code blocks, tables, headings,
HTML comments, images and snippet includes are left out. A link counts as its text (the URL is
dropped); an inline code span counts as one word. A sentence ends at ``.``, ``!`` or ``?``
followed by a space; a bullet item or paragraph ends one too. A word holds a letter or a digit.

Targets (``--check``):

- median sentence ≤ 25 words (every checked page);
- no bullet over 60 words (docs/status.md);
- the first table within the first 40 lines (every checked page except docs/status.md, whose
  bullets each link to their table);
- no ``issue N`` mention.

Pure Python, no dependencies beyond the standard library.
"""
from __future__ import annotations

import argparse
import re
import statistics
import sys
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CHECKED = ("README.md", "docs/status.md", "docs/identify.md")
"""The pages ``--check`` checks when none are named (BENCHMARKS.md can be named too)."""

MEDIAN_MAX = 25
LONG = 40
BULLET_MAX = 60
TABLE_LINE_MAX = 40

ISSUE = re.compile(r"\bissues? #?[0-9]+", re.IGNORECASE)
FENCE = re.compile(r"^\s*(```|~~~)")
BULLET = re.compile(r"^(\s*)([-*+]|\d+[.)])\s+(.*)$")
IMAGE = re.compile(r"!\[[^\]]*\]\([^)]*\)")
LINK = re.compile(r"\[([^\]]*)\]\([^)]*\)")
CODE = re.compile(r"`[^`]+`")
ABBREV = re.compile(r"\b(e\.g|i\.e|etc|vs|cf|approx|Fig|resp|al|no)\.(?=\s)", re.IGNORECASE)
SENTENCE_END = re.compile(r"(?<=[.!?])[\"”')\]*_]*\s+")
WORD = re.compile(r"[A-Za-z0-9θτκΔ]")


@dataclass
class Metrics:
    path: str
    sentences: list[int] = field(default_factory=list)     # words per sentence
    texts: list[tuple[int, int, str]] = field(default_factory=list)   # (block's line, words, sentence)
    bullets: list[int] = field(default_factory=list)       # words per top-level bullet item
    first_table: int | None = None                         # 1-based line of the first table row
    issues: list[tuple[int, str]] = field(default_factory=list)

    @property
    def median(self) -> float:
        return statistics.median(self.sentences) if self.sentences else 0.0

    @property
    def long_share(self) -> float:
        return sum(n > LONG for n in self.sentences) / len(self.sentences) if self.sentences else 0.0

    @property
    def longest_bullet(self) -> int:
        return max(self.bullets, default=0)


def words(text: str) -> int:
    """Words of ``text`` once links are their text and code spans one word each."""
    text = IMAGE.sub(" ", text)
    text = LINK.sub(r"\1", text)
    text = CODE.sub(" code ", text)
    return sum(bool(WORD.search(t)) for t in text.split())


def split_sentences(text: str) -> list[str]:
    """``text`` (one paragraph or bullet item) cut into sentences."""
    text = IMAGE.sub(" ", text)
    text = LINK.sub(r"\1", text)
    text = CODE.sub(lambda m: m.group(0).replace(".", "·").replace("?", "¿").replace("!", "¡"), text)
    text = ABBREV.sub(lambda m: m.group(1), text)
    return [s for s in SENTENCE_END.split(text) if s.strip()]


def blocks(lines: list[str]):
    """(kind, first line number, text) of each prose block: 'para' or 'bullet' (top-level or nested)."""
    in_code = in_comment = False
    cur: list[str] = []
    kind, start = "para", 0

    def flush():
        nonlocal cur
        out = (kind, start, " ".join(cur)) if cur else None
        cur = []
        return out

    for i, raw in enumerate(lines, 1):
        line = raw.rstrip()
        if FENCE.match(line):
            if (b := flush()):
                yield b
            in_code = not in_code
            continue
        if in_code:
            continue
        if in_comment or line.lstrip().startswith("<!--"):
            if (b := flush()):
                yield b
            in_comment = "-->" not in line
            continue
        s = line.strip()
        s = re.sub(r"^(>\s*)+", "", s)                     # block quotes are text
        if (not s or s.startswith("#") or s.startswith("|") or s.startswith("--8<--")
                or s.startswith("!!!") or s.startswith("???") or re.fullmatch(r"(!\[[^\]]*\]\([^)]*\)\s*)+", s)
                or re.fullmatch(r"[-*_=]{3,}", s)):
            if (b := flush()):
                yield b
            continue
        m = BULLET.match(line.lstrip("> ") if line.lstrip().startswith(">") else line)
        if m:
            if (b := flush()):
                yield b
            kind, start = ("bullet" if not m.group(1) else "subbullet"), i
            cur = [m.group(3)]
            continue
        if not cur:
            kind, start = "para", i
        cur.append(s)
    if (b := flush()):
        yield b


def measure(path: Path, name: str | None = None) -> Metrics:
    lines = path.read_text(encoding="utf-8").splitlines()
    m = Metrics(name or str(path))
    in_code = False
    for i, line in enumerate(lines, 1):
        if FENCE.match(line):
            in_code = not in_code
            continue
        if in_code:
            continue
        if m.first_table is None and line.lstrip().startswith("|"):
            m.first_table = i
        for hit in ISSUE.finditer(line):
            m.issues.append((i, hit.group(0)))
    last_bullet = None
    for kind, start, text in blocks(lines):
        for s in split_sentences(text):
            if (k := words(s)):
                m.sentences.append(k)
                m.texts.append((start, k, s))
        if kind == "bullet":
            m.bullets.append(words(text))
            last_bullet = len(m.bullets) - 1
        elif kind == "subbullet" and last_bullet is not None:
            m.bullets[last_bullet] += words(text)      # a nested item belongs to its bullet
        else:
            last_bullet = None
    return m


def failures(m: Metrics) -> list[str]:
    """The targets ``m``'s page misses (see the module's docstring)."""
    out = []
    if m.median > MEDIAN_MAX:
        out.append(f"median sentence {m.median:g} words > {MEDIAN_MAX}")
    is_status = Path(m.path).name == "status.md"
    if is_status and m.longest_bullet > BULLET_MAX:
        out.append(f"a bullet of {m.longest_bullet} words > {BULLET_MAX}")
    if not is_status and (m.first_table is None or m.first_table > TABLE_LINE_MAX):
        out.append(f"first table at line {m.first_table} (> {TABLE_LINE_MAX})")
    out += [f"line {ln}: '{hit}'" for ln, hit in m.issues]
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("pages", nargs="*", type=Path, help=f"Markdown files (default with --check: {', '.join(CHECKED)})")
    ap.add_argument("--check", action="store_true", help="exit 1 if a page misses a target")
    ap.add_argument("--long", type=int, metavar="N", help="also list the sentences over N words")
    ap.add_argument("--root", type=Path, default=ROOT, help="the checkout (default: this one)")
    a = ap.parse_args(argv)
    pages = a.pages or [a.root / p for p in CHECKED]
    bad = 0
    print(f"{'page':28} {'sentences':>9} {'median':>6} {'>40 w':>6} {'bullet max':>10} {'table at':>8} {'issue N':>7}")
    for p in pages:
        m = measure(p, str(p.relative_to(a.root)) if p.is_absolute() and p.is_relative_to(a.root) else str(p))
        print(f"{m.path:28} {len(m.sentences):9d} {m.median:6g} {100 * m.long_share:5.0f}% "
              f"{m.longest_bullet:10d} {str(m.first_table or '-'):>8} {len(m.issues):7d}")
        if a.long is not None:
            for line, k, text in m.texts:
                if k > a.long:
                    print(f"  {m.path}:{line} ({k} words) {text}")
        if a.check:
            for f in failures(m):
                bad += 1
                print(f"  {m.path}: {f}", file=sys.stderr)
    return 1 if bad else 0


if __name__ == "__main__":
    raise SystemExit(main())
