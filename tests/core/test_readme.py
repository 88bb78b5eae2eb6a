"""The README and docs/ say true things: current tables, real commands, live links."""

import re
from pathlib import Path

import pytest

from amrst.cli import build_parser
from amrst.params.doc import PAGE, parameters_page

ROOT = Path(__file__).resolve().parents[2]
README = ROOT / "README.md"
PAGES = [README, *sorted((ROOT / "docs").glob("*.md"))]


def _text(path: Path) -> str:
    return path.read_text(encoding="utf-8")


def test_parameters_page_matches_the_code() -> None:
    assert _text(PAGE) == parameters_page(), "run: python -m amrst.params.doc"


def test_readme_is_short() -> None:
    assert len(_text(README).splitlines()) <= 300


def test_readme_names_the_two_setup_commands() -> None:
    text = _text(README)
    assert "bash packaging/bootstrap.sh app" in text
    assert "bash packaging/bootstrap.sh test" in text
    ci = _text(ROOT / ".ci" / "run")
    assert "packaging/bootstrap.sh test" in ci
    bootstrap = _text(ROOT / "packaging" / "bootstrap.sh")
    assert '-m "not perf"' in bootstrap, "the test command deselects the perf marker"


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_links_and_pictures_exist(page: Path) -> None:
    targets = re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", _text(page))
    missing = [
        t
        for t in targets
        if "://" not in t and not (page.parent / t).resolve().exists()
    ]
    assert not missing, f"{page.name} links to missing files: {missing}"


def _subparsers(parser):
    actions = [a for a in parser._actions if a.choices and isinstance(a.choices, dict)]
    return actions[0].choices if actions else {}


def _command_lines(text: str) -> list[str]:
    """Every `amrst ...` invocation in code spans and fenced code blocks."""
    spans = re.findall(r"`(amrst [^`]+)`", text)
    blocks = re.findall(r"```bash\n(.*?)```", text, flags=re.S)
    lines = [
        line.strip()
        for block in blocks
        for line in block.replace("\\\n", " ").splitlines()
        if line.strip().startswith("amrst ")
    ]
    return spans + lines


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_documented_commands_and_options_exist(page: Path) -> None:
    commands = _subparsers(build_parser())
    wrong = []
    for line in _command_lines(_text(page)):
        words = line.split("#", 1)[0].split()[1:]
        while words and words[0].startswith("--") and words[0] != "--help":
            words = words[1:]  # global options such as --debug
        if not words or words[0] in ("--help", "--version", "COMMAND"):
            continue
        parser = commands.get(words[0])
        if parser is None:
            wrong.append(line)
            continue
        sub = _subparsers(parser)
        if sub and len(words) > 1 and words[1] in sub:
            parser = sub[words[1]]
        known = {s for a in parser._actions for s in a.option_strings}
        flags = {w.strip("[]|.,") for w in words if w.lstrip("[").startswith("--")}
        wrong += [f"{line}: {f}" for f in sorted(flags - known)]
    assert not wrong, f"{page.name} names commands or options amrst lacks: {wrong}"


def test_docs_cite_no_paths_outside_a_clone() -> None:
    for page in PAGES:
        text = _text(page)
        assert "STYLE.md" not in text, page.name
        assert "../shared" not in text, page.name
        assert not re.search(r"\bissue \d+", text, flags=re.I), page.name
