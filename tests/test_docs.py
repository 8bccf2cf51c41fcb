"""The documentation holds together: cited equations resolve, relative links resolve, and no text
names a work item instead of the thing it is about.

- Every equation number cited in the project's Python files (companion/, behaviors/, sim/,
  harness/, bench/, tests/) or its Markdown pages must be restated in docs/method.md, either as an
  equation tag "(L)" or as "eq. L". A range such as "eq. 3.26–3.31" is expanded into every number
  it spans; lists ("eq. 4.4, 4.6, 4.12", "eq. B.10/B.12", "eq. 5.13 and 5.10") are split.
- Every relative link in README.md and docs/*.md (and the other Markdown pages) points to a file
  that exists, and its #anchor, if any, to a heading of that file (GitHub's slugs) or an explicit
  HTML anchor.
- No text file names a work item by number (an issue, a pull request): code, help texts, test
  names and pages say what the thing is.

Fast and offline: reads files only.
"""
from __future__ import annotations

import os
import re
import subprocess
import unicodedata
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
METHOD = ROOT / "docs" / "method.md"

#: the folders whose Python files are the project's own
PYTHON_DIRS = ("companion", "behaviors", "sim", "harness", "bench", "tests")
#: folders never looked into (virtual environments, caches, build output)
SKIP_DIRS = {".git", ".venv", "venv", "__pycache__", ".pytest_cache", ".mypy_cache", ".ruff_cache",
             "node_modules", "build", "dist"}
#: text files checked for work-item numbers, by suffix; files without a suffix under .ci/ as well
TEXT_SUFFIXES = {".py", ".md", ".toml", ".json", ".txt", ".parm", ".cfg", ".ini", ".service", ".yaml",
                 ".yml", ".sh", ".gitignore"}

# ------------------------------------------------------------------ file discovery


def _repository_files() -> list[Path]:
    """Tracked and untracked-but-not-ignored files (git), else a walk that skips SKIP_DIRS."""
    try:
        out = subprocess.run(["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
                             cwd=ROOT, capture_output=True, check=True, timeout=30).stdout
        names = [n for n in out.decode("utf-8", "replace").split("\0") if n]
        files = [ROOT / n for n in names]
        return sorted({f for f in files if f.is_file() and not SKIP_DIRS.intersection(f.relative_to(ROOT).parts)})
    except (OSError, subprocess.SubprocessError):
        found = []
        for folder, dirs, names in os.walk(ROOT):
            dirs[:] = [d for d in dirs if d not in SKIP_DIRS and not d.endswith(".egg-info")]
            found.extend(Path(folder) / n for n in names)
        return sorted(found)


def _relative(path: Path) -> str:
    return path.relative_to(ROOT).as_posix()


def _python_files() -> list[Path]:
    return [f for f in _repository_files() if f.suffix == ".py" and f.relative_to(ROOT).parts[0] in PYTHON_DIRS]


def _markdown_files() -> list[Path]:
    return [f for f in _repository_files() if f.suffix == ".md"]


def _text_files() -> list[Path]:
    files = []
    for f in _repository_files():
        parts = f.relative_to(ROOT).parts
        if f.suffix in TEXT_SUFFIXES or f.name in TEXT_SUFFIXES or (parts[0] == ".ci" and not f.suffix):
            files.append(f)
    return files


# ------------------------------------------------------------------ (a) equation labels

_LABEL = r"(?:[A-Z]\.\d+|\d+(?:\.\d+)?)"
#: "eq. 3.57", "Eq. 5.16", "eq. (9)", "eqs. 7–8", "equation 3.39", followed by more labels joined by
#: a range dash, a comma, a slash or "and"
CITATION = re.compile(
    rf"\b[Ee]q(?:s|uations?)?\.?\s*\(?({_LABEL})\)?((?:\s*(?:[–—-]|,|/|\band\b)\s*\(?{_LABEL}\)?)*)")
_JOINED = re.compile(rf"\s*([–—-]|,|/|\band\b)\s*\(?({_LABEL})\)?")
#: a range spanning more numbers than this is a misreading, not a citation
MAX_RANGE = 60


def _split_label(label: str) -> tuple[str, int] | None:
    """"5.28" → ("5.", 28); "B.10" → ("B.", 10); "7" → ("", 7)."""
    match = re.fullmatch(r"([A-Z]?\d+\.|[A-Z]\.)?(\d+)", label)
    if not match:
        return None
    return match.group(1) or "", int(match.group(2))


def expand_citation(first: str, rest: str) -> list[str]:
    """The labels one citation names: ranges expanded into every number they span (when both ends
    share a chapter), lists split."""
    labels = [first]
    previous = first
    for joiner, label in _JOINED.findall(rest):
        if joiner in "–—-":
            low, high = _split_label(previous), _split_label(label)
            if low and high and low[0] == high[0] and 0 < high[1] - low[1] <= MAX_RANGE:
                labels.extend(f"{low[0]}{n}" for n in range(low[1] + 1, high[1]))
        labels.append(label)
        previous = label
    return labels


def cited_labels(text: str) -> set[str]:
    labels: set[str] = set()
    for match in CITATION.finditer(text):
        labels.update(expand_citation(match.group(1), match.group(2)))
    return labels


def label_resolves(label: str, method_text: str) -> bool:
    """The label is an equation tag "(L)" or is written "eq. L" (not a prefix of a longer number)."""
    escaped = re.escape(label)
    return re.search(rf"\({escaped}\)|\beq\.\s*{escaped}(?!\.?\d)", method_text) is not None


def test_citation_parser():
    assert cited_labels("SVF (eq. 3.26–3.31)") == {f"3.{n}" for n in range(26, 32)}
    assert cited_labels("(eq. 4.4, 4.6, 4.12), the") == {"4.4", "4.6", "4.12"}
    assert cited_labels("Pitch (App. B, eq. B.10/B.12): q̇") == {"B.10", "B.12"}
    assert cited_labels("eq. 5.13 and 5.10") == {"5.13", "5.10"}
    assert cited_labels("fits eq. 7–8 at the end; paper eq. 11") == {"7", "8", "11"}
    assert cited_labels("eq. 3.39, R² ≥ 0.61, eq. (9)") == {"3.39", "9"}
    assert cited_labels("equilibrium q = 0; the equations of motion") == set()
    assert label_resolves("3.5", "ψ̇ = r   (3.5)")
    assert not label_resolves("3.5", "Kp = a22²/(2·b2)   (3.57)")
    assert not label_resolves("3", "see eq. 3.39")


def test_every_cited_equation_is_in_method_md():
    method_text = METHOD.read_text(encoding="utf-8")
    missing: dict[str, list[str]] = {}
    sources = _python_files() + [f for f in _markdown_files() if f != METHOD]
    for path in sources:
        text = path.read_text(encoding="utf-8", errors="replace")
        for line_number, line in enumerate(text.splitlines(), 1):
            for label in sorted(cited_labels(line)):
                if not label_resolves(label, method_text):
                    missing.setdefault(label, []).append(f"{_relative(path)}:{line_number}")
    assert not missing, "equation labels cited but not in docs/method.md:\n" + "\n".join(
        f"  {label}: {', '.join(places)}" for label, places in sorted(missing.items()))


# ------------------------------------------------------------------ (b) relative links

_FENCE = re.compile(r"^(```|~~~).*?^\1\s*$", re.M | re.S)
_CODE_SPAN = re.compile(r"(`+)(.+?)\1", re.S)
_LINK = re.compile(r"!?\[[^\]]*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
_HEADING = re.compile(r"^(#{1,6})\s+(.*?)\s*#*\s*$", re.M)
_HTML_ANCHOR = re.compile(r"<a\s+(?:id|name)=\"([^\"]+)\"", re.I)


def _strip_code(text: str) -> str:
    text = _FENCE.sub("", text)
    return _CODE_SPAN.sub(lambda m: "x", text)


def github_slug(heading: str) -> str:
    """GitHub's heading anchor: the rendered text lower-cased, everything but letters, marks,
    numbers, connector punctuation, hyphens and spaces dropped, spaces made hyphens."""
    text = re.sub(r"!?\[([^\]]*)\]\([^)]*\)", r"\1", heading)  # a link renders as its text
    text = re.sub(r"<[^>]+>", "", text)  # inline HTML
    text = text.replace("`", "").lower()
    kept = [c for c in text if c in "- " or unicodedata.category(c)[0] in "LMN" or unicodedata.category(c) == "Pc"]
    return "".join(kept).replace(" ", "-")


def anchors(path: Path) -> set[str]:
    text = path.read_text(encoding="utf-8", errors="replace")
    seen: dict[str, int] = {}
    found = set(_HTML_ANCHOR.findall(text))
    for _level, heading in _HEADING.findall(_FENCE.sub("", text)):
        slug = github_slug(heading)
        count = seen.get(slug, 0)
        seen[slug] = count + 1
        found.add(slug if count == 0 else f"{slug}-{count}")
    return found


def test_github_slug():
    assert github_slug("1. Yaw model and SVF-RLS identification (thesis ch. 3)") == \
        "1-yaw-model-and-svf-rls-identification-thesis-ch-3"
    assert github_slug("Lockstep (`python -m sim run --lockstep`)") == "lockstep-python--m-sim-run---lockstep"
    assert github_slug("10. Steady state (Hegrenæs et al.)") == "10-steady-state-hegrenæs-et-al"


def test_relative_links_resolve():
    broken = []
    for page in _markdown_files():
        text = _strip_code(page.read_text(encoding="utf-8", errors="replace"))
        for target in _LINK.findall(text):
            if re.match(r"^[a-z][a-z0-9+.-]*:", target, re.I):  # http:, https:, mailto:
                continue
            file_part, _, anchor = target.partition("#")
            destination = (page.parent / file_part).resolve() if file_part else page
            if not destination.exists():
                broken.append(f"{_relative(page)}: {target} (no such file)")
                continue
            if anchor and destination.suffix == ".md" and anchor not in anchors(destination):
                broken.append(f"{_relative(page)}: {target} (no such heading)")
    assert not broken, "broken relative links:\n" + "\n".join(f"  {b}" for b in broken)


# ------------------------------------------------------------------ (c) work-item numbers

#: a work item named by its number, in any case: the word issue (or issues) followed by a number,
#: with a space, hyphen, underscore or hash between, or run together as in a test name; a pull
#: request, bug or ticket with a hash and a number; "fixes"/"closes"/"see" with a hash and a number;
#: a hash and a number alone in parentheses; GitHub's GH-number (examples in test_work_item_pattern)
WORK_ITEM = re.compile(
    r"(?<![A-Za-z])issues?[\s_-]*#?\d+"
    r"|\b(?:PR|pull[\s-]+requests?|bugs?|tickets?|fix(?:es|ed)?|close[sd]?|resolve[sd]?|refs?|see)\s*#\d+\b"
    r"|\(#\d+\)"
    r"|\bGH-\d+\b",
    re.I,
)


def test_work_item_pattern():
    flagged = ["iss" + "ue 10", "Iss" + "ue-10", "iss" + "ues 9 and 10", "(iss" + "ue 14)", "test_iss" + "ue10_x",
               "PR #" + "3", "fix" + "es #12", "(#" + "12)"]
    for text in flagged:
        assert WORK_ITEM.search(text), text
    for text in ["color: #333;", "# 1 step", "channel #2 of", "'#010x'", "ISSUED 10 times", "tissue 3"]:
        assert not WORK_ITEM.search(text), text


def test_no_text_file_names_a_work_item():
    offenders = []
    for path in _text_files():
        try:
            text = path.read_text(encoding="utf-8")
        except (UnicodeDecodeError, OSError):
            continue
        for line_number, line in enumerate(text.splitlines(), 1):
            for match in WORK_ITEM.finditer(line):
                offenders.append(f"{_relative(path)}:{line_number}: {match.group(0)!r}")
    assert not offenders, f"{len(offenders)} work-item references (name the thing instead):\n" + "\n".join(
        f"  {o}" for o in offenders)


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(pytest.main([__file__, "-q"]))
