"""The documentation's shape: a short README with its set-up commands first, the same test
command as CI, links that resolve, and a reason on every skipped code block. (The code blocks
themselves run through the repository's conftest.py.)"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
README = REPO / "README.md"
DOCS = sorted([README, *(REPO / "docs").glob("*.md")])

# the run directory named, so that the course path reuses this run (runs/sb3 is its step 2)
INSTALL_AND_TRAIN = "pip install -e . && python -m jaxcart.train --out runs/sb3"
TEST_COMMAND = (
    "pip install -e '.[test]' && ruff check . && ruff format --check . && python -m pytest -q"
)
LINK = re.compile(r"\]\(([^)\s]+)\)")
SKIP = re.compile(r"<!--\s*skip:\s*(\w+)(.*?)-->")


def github_anchor(heading: str) -> str:
    """The anchor GitHub gives a Markdown heading: lower case, punctuation dropped, spaces
    to hyphens (``## 5. SB3 (PyTorch)`` -> ``5-sb3-pytorch``)."""
    text = heading.strip().lower().replace("`", "")
    return re.sub(r"[^\w\- ]", "", text).replace(" ", "-")


def anchors(path: Path) -> set[str]:
    """The anchors of every heading in a Markdown file, outside code blocks."""
    found, in_code = set(), False
    for line in path.read_text().splitlines():
        if line.startswith("```"):
            in_code = not in_code
        elif not in_code and line.startswith("#"):
            found.add(github_anchor(line.lstrip("#")))
    return found


def test_readme_is_a_short_front_door_with_the_two_commands_first():
    lines = README.read_text().splitlines()
    assert len(lines) <= 150, f"README.md has {len(lines)} lines; move depth to docs/"
    first = lines[:40]
    assert INSTALL_AND_TRAIN in first, "the install-and-train command must be in lines 1-40"
    assert TEST_COMMAND in first, "the test command must be in lines 1-40"


def test_ci_runs_the_readme_test_command():
    ci = (REPO / ".ci" / "run").read_text().splitlines()
    assert TEST_COMMAND in ci, ".ci/run must run exactly the README's test command"


def test_the_test_command_leaves_the_slow_tier_to_ci():
    """``python -m pytest`` deselects the slow tier (pyproject.toml's addopts); .ci/run runs it
    after the README's command."""
    import tomllib

    pyproject = tomllib.loads((REPO / "pyproject.toml").read_text())
    assert "-m 'not slow'" in pyproject["tool"]["pytest"]["ini_options"]["addopts"]
    ci = (REPO / ".ci" / "run").read_text().splitlines()
    readme_at = ci.index(TEST_COMMAND)
    slow_at = next(i for i, line in enumerate(ci) if "python -m pytest -q -m slow" in line)
    assert slow_at > readme_at, ".ci/run must run the slow tier after the README's command"


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: str(p.relative_to(REPO)))
def test_relative_links_resolve(doc: Path):
    text = re.sub(r"```.*?```", "", doc.read_text(), flags=re.DOTALL)
    broken = []
    for target in LINK.findall(text):
        if re.match(r"[a-z]+:", target):
            continue  # http(s), mailto: not checked offline
        file_part, _, anchor = target.partition("#")
        path = (doc.parent / file_part).resolve() if file_part else doc
        if not path.exists():
            broken.append(target)
        elif anchor and path.suffix == ".md" and anchor not in anchors(path):
            broken.append(target)
    assert not broken, f"{doc.name}: links to nothing: {broken}"


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: str(p.relative_to(REPO)))
def test_every_skipped_block_says_why(doc: Path):
    for action, reason in SKIP.findall(doc.read_text()):
        assert action == "next", f"{doc.name}: use `skip: next` before each long block"
        # "why", or if(CONDITION, reason="why") for a block that needs an optional extra
        assert re.fullmatch(r'\s*(?:"[^"]{10,}"|if\(\w[\w .]*, reason="[^"]{10,}"\))\s*', reason), (
            f"{doc.name}: a skip needs a reason in quotes, got {reason.strip()!r}"
        )


EXCERPT = re.compile(
    r'<!--\s*skip:\s*next\s+"excerpt of ([\w/.]+)"\s*-->\s*```python\n(.*?)```', re.S
)


def excerpts(doc: Path) -> list[tuple[str, str]]:
    """``(path, code)`` of every block a document marks as an excerpt of a repository file."""
    return EXCERPT.findall(doc.read_text())


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: p.name)
def test_code_excerpts_still_stand_in_their_files(doc: Path):
    """An excerpt is a run of consecutive lines of its file, indentation included, so a
    change to the code shows here: update the excerpt (and the text around it) to match."""
    for path, code in excerpts(doc):
        source = (REPO / path).read_text()
        assert code in source, (
            f"{doc.name}: this excerpt of {path} is no longer in the file; copy the current "
            f"lines into the document:\n{code}"
        )


def test_the_course_quotes_excerpts_of_the_network_and_ppo():
    quoted = {path for path, _ in excerpts(REPO / "docs" / "course.md")}
    assert quoted == {"jaxcart/core/ppo.py", "jaxcart/core/networks.py"}
