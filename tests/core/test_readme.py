"""The README's parameter table is generated from the code and must stay current."""

from pathlib import Path

from amrst.params.doc import BEGIN, END, parameter_table

README = Path(__file__).resolve().parents[2] / "README.md"


def test_parameter_table_matches_the_code() -> None:
    text = README.read_text(encoding="utf-8")
    table = text.split(BEGIN, 1)[1].split(END, 1)[0].strip()
    assert table == parameter_table().strip(), "run: python -m amrst.params.doc"


def test_readme_names_the_two_setup_commands() -> None:
    text = README.read_text(encoding="utf-8")
    assert "bash packaging/bootstrap.sh app" in text
    assert "bash packaging/bootstrap.sh test" in text
    ci = (README.parent / ".ci" / "run").read_text(encoding="utf-8")
    assert "packaging/bootstrap.sh test" in ci
