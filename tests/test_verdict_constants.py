"""The verdict constants are named once, in rangeslam.verdict.thresholds, and the README's
verdict table lists every one of them (issue 42 item 4: at most 12 in the end; the count may
only go down from where it stands)."""

import re
from pathlib import Path

from rangeslam.verdict import thresholds

README = Path(__file__).resolve().parents[1] / "README.md"
# the count today; issue 42 asks for at most 12: lower it as constants go
MOST = 12


def _readme_names() -> set[str]:
    text = README.read_text(encoding="utf-8")
    table = text[text.index("| `CHI2_LEVEL` |") :]
    table = table[: table.index("\n\n")]
    return {
        name
        for row in table.splitlines()
        for name in re.findall(r"`([A-Z][A-Z0-9_]+)`", row.split("|")[1])
    }


def test_every_verdict_constant_is_in_the_readme_table_and_no_other():
    """The README's table and thresholds.__all__ name the same constants."""
    assert _readme_names() == set(thresholds.__all__)


def test_the_number_of_verdict_constants_does_not_grow():
    """At most MOST names in thresholds (every one a level or a count with its meaning)."""
    assert len(thresholds.__all__) <= MOST, sorted(thresholds.__all__)


def test_no_constant_outside_thresholds_shadows_one_of_its_names():
    """No module of the package assigns a name thresholds holds (no copy under the same name)."""
    root = Path(thresholds.__file__).resolve().parents[1]
    names = "|".join(thresholds.__all__)
    pattern = re.compile(rf"^({names})\s*=", re.MULTILINE)
    offenders = [
        str(path.relative_to(root))
        for path in root.rglob("*.py")
        if path.name != "thresholds.py" and pattern.search(path.read_text(encoding="utf-8"))
    ]
    assert offenders == []
