"""The documents a newcomer reads hold together: every relative link in README.md and docs/*.md
points at a file that exists and, with a ``#anchor``, at a heading of that file; the README
stays short enough to read (issue 33.7) and every benchmark table lives in docs/performance.md
with its command, machine and date."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
LINK = re.compile(r"(?<!!)\[[^\]]*\]\(([^)\s]+)\)")
FENCE = re.compile(r"^```.*?^```", re.S | re.M)
CODE = re.compile(r"`[^`\n]*`")


def prose(text: str) -> str:
    """The text without fenced blocks and inline code (where brackets are not links)."""
    return CODE.sub("", FENCE.sub("", text))


def slug(heading: str) -> str:
    """A heading's anchor as GitHub makes it: lower case, punctuation dropped, spaces to -."""
    text = heading.strip().lower().replace("`", "")
    return re.sub(r"[^\w\- ]", "", text).replace(" ", "-")


def anchors(path: Path) -> set[str]:
    seen: dict[str, int] = {}
    out = set()
    for line in FENCE.sub("", path.read_text(encoding="utf-8")).splitlines():
        m = re.match(r"#{1,6} (.*)", line)
        if not m:
            continue
        base = slug(m.group(1))
        n = seen.get(base, 0)
        seen[base] = n + 1
        out.add(base if n == 0 else f"{base}-{n}")
    return out


def links(path: Path) -> list[str]:
    return [m.group(1) for m in LINK.finditer(prose(path.read_text(encoding="utf-8")))]


def test_slugs_are_githubs() -> None:
    assert slug("Measuring together, acting on time") == "measuring-together-acting-on-time"
    assert slug("`missing-link info URL [--json]`") == "missing-link-info-url---json"
    assert slug("ROS 2 through Zenoh (`zenoh` publisher)") == "ros-2-through-zenoh-zenoh-publisher"


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_relative_link_points_at_a_file_and_heading(doc: Path) -> None:
    broken = []
    for target in links(doc):
        if re.match(r"[a-z][a-z0-9+.-]*:", target):  # http:, https:, mailto: ...
            continue
        file, _, anchor = target.partition("#")
        where = (doc.parent / file).resolve() if file else doc
        if not where.exists():
            broken.append(f"{target}: no such file")
        elif anchor and where.suffix == ".md" and anchor not in anchors(where):
            broken.append(f"{target}: no heading #{anchor} in {where.relative_to(ROOT)}")
    assert not broken, f"{doc.relative_to(ROOT)}: " + "; ".join(broken)


def test_the_readme_is_short_and_its_tables_are_few() -> None:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    assert len(text.splitlines()) <= 250
    tables = re.findall(r"^\|---.*$", prose(text), re.M)
    assert len(tables) <= 1  # the performance summary; every other table is in docs/


def test_every_benchmark_table_says_its_command_machine_and_date() -> None:
    text = (ROOT / "docs" / "performance.md").read_text(encoding="utf-8")
    sections = re.split(r"^## ", text, flags=re.M)[1:]
    assert len(sections) >= 15
    for section in sections:
        title = section.splitlines()[0]
        if "|---" not in section and "```" not in section:
            continue  # (prose only)
        assert "*Machine:" in section and "Date:" in section, f"{title}: no machine or date"
        assert "bench/" in section or "missing-link" in section, f"{title}: no command"


def test_the_readme_stays_inside_the_repository() -> None:
    """The README names nothing outside the repository (no ``../`` path, no link out of it,
    checked above) and no commit hash (a figure's reference is said in words; the commits are
    in docs/performance.md's tables)."""
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    assert "../" not in text, "README.md names a path outside the repository"
    assert (ROOT / "LICENSE").is_file(), "pyproject.toml declares a licence: LICENSE says it"
    hashes = [h for h in re.findall(r"\b[0-9a-f]{7,40}\b", text) if re.search(r"[a-f]", h)]
    assert not [h for h in hashes if re.search(r"\d", h)], f"commit hashes in README.md: {hashes}"


@pytest.mark.parametrize("doc", DOCS[1:], ids=lambda p: p.name)
def test_no_document_sends_a_reader_outside_the_repository(doc: Path) -> None:
    """A user with a clone has what the docs name: the wire protocol is docs/protocol.md."""
    assert "../shared" not in doc.read_text(encoding="utf-8"), f"{doc.name} names ../shared"


def test_what_ships_names_only_documents_the_repository_has() -> None:
    """The package (what a wheel holds: the AVR C, its Makefile, the simulator's modules) names
    a document only if docs/ has it: the golden vectors are docs/protocol.md's, not a spec page
    outside the repository."""
    pkg = ROOT / "src" / "missing_link"
    named = {
        (name, str(path.relative_to(ROOT)))
        for path in pkg.rglob("*")
        if path.suffix in {".py", ".c", ".h", ".mjs"} or path.name == "Makefile"
        for name in re.findall(r"\b[\w-]+\.md\b", path.read_text("utf-8", errors="replace"))
    }
    have = {p.name for p in DOCS}
    assert not [(n, where) for n, where in sorted(named) if n not in have]


def test_the_protocols_golden_vectors_are_the_tests() -> None:
    """Every fully given request and reply in docs/protocol.md's vector table, and its SIF, is
    one the tests check the implementations against (tests/vectors.py)."""
    from .vectors import SIF, VECTORS, h

    text = (ROOT / "docs" / "protocol.md").read_text(encoding="utf-8")
    table = text[text.index("## Golden vectors") :]
    given = {pair for _, req, rep in VECTORS for pair in (req, rep)}
    rows = re.findall(r"^\| [^|]+ \| ([0-9a-f ]+) \| ([0-9a-f ]+) \|$", table, re.M)
    assert len(rows) >= 3, "the vector table lost its rows"
    for req, rep in rows:
        assert {h(req), h(rep)} <= given, (req, rep)
    assert h(re.findall(r"`(ed [0-9a-f ]+)`", table)[0]) == SIF


def thread_names() -> dict[str, str]:
    """Every thread the host side, the daemon and the faces start, by the name it gets (an
    f-string's fixed start, then ``<``), and where."""
    import ast

    found = {}
    for top in ("host", "daemon", "publishers"):
        for path in sorted((ROOT / "src" / "missing_link" / top).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
                if not (
                    isinstance(node, ast.Call) and ast.unparse(node.func) == "threading.Thread"
                ):
                    continue
                name = next((k.value for k in node.keywords if k.arg == "name"), None)
                if isinstance(name, ast.Constant):
                    found[str(name.value)] = str(path.relative_to(ROOT))
                elif isinstance(name, ast.JoinedStr) and isinstance(name.values[0], ast.Constant):
                    found[f"{name.values[0].value}<"] = str(path.relative_to(ROOT))
                elif name is None:
                    found[f"(unnamed, line {node.lineno})"] = str(path.relative_to(ROOT))
    return found


def test_every_thread_of_the_daemon_is_in_the_architecture() -> None:
    """docs/architecture.md's table of threads names every thread the daemon's rooms start."""
    text = (ROOT / "docs" / "architecture.md").read_text(encoding="utf-8")
    table = text.split("## The threads of a running daemon", 1)[1]
    names = set(re.findall(r"^\| `([^`]+)`", table, re.M))
    found = thread_names()
    assert "listener" in found and "j2a:reactor" in found  # (the walk sees them)
    missing = {n: where for n, where in found.items() if not any(t.startswith(n) for t in names)}
    assert not missing, f"threads not in docs/architecture.md: {missing}"
