"""The documentation's examples run: every ``pycon`` block of docs/*.md is a doctest."""

from __future__ import annotations

import doctest
import re

import pytest

from tests.conftest import ROOT

DOCS = ROOT / "docs"
BLOCK = re.compile(r"^```pycon\n(.*?)^```", re.S | re.M)


def pycon_blocks(text: str) -> str:
    """The ``pycon`` code blocks of a markdown page, one after the other."""
    return "\n".join(block for block in BLOCK.findall(text))


def _pages() -> list[str]:
    return sorted(p.name for p in DOCS.glob("*.md") if "```pycon" in p.read_text())


def test_pycon_blocks_are_found():
    text = "x\n```pycon\n>>> 1 + 1\n2\n\n```\ny\n```pycon\n>>> 3\n3\n```\n"
    assert pycon_blocks(text) == ">>> 1 + 1\n2\n\n\n>>> 3\n3\n"
    assert "python-api.md" in _pages()


@pytest.mark.parametrize("page", _pages())
def test_doc_examples(page, monkeypatch, tmp_path):
    monkeypatch.chdir(ROOT)  # the examples name files relative to the repository
    monkeypatch.setenv("MCRT_CACHE_DIR", str(tmp_path / "cache"))
    text = pycon_blocks((DOCS / page).read_text())
    parser = doctest.DocTestParser()
    test = parser.get_doctest(text, {}, page, str(DOCS / page), 0)
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    report: list[str] = []
    runner.run(test, out=report.append)
    assert runner.tries > 0 and runner.failures == 0, "\n".join(report)


def test_readme_is_short_and_its_commands_table_is_the_parser():
    """README.md stays an overview (the reference is in docs/), and its table of
    commands says what each subcommand's own declaration says, in the same order."""
    import argparse

    from mcrt.cli import COMMANDS, build_parser

    readme = (ROOT / "README.md").read_text()
    assert len(readme.splitlines()) <= 200
    assert "bash scripts/demo.sh" in readme and "bash scripts/test.sh" in readme
    rows = re.findall(r"^\| `mcrt (\w+)` \| (.*?) \|", readme, flags=re.M)
    action = next(a for a in build_parser()._actions
                  if isinstance(a, argparse._SubParsersAction))
    declared = [(c.dest, c.help) for c in action._choices_actions]
    assert rows == declared and [name for name, _ in rows] == list(COMMANDS)


@pytest.mark.parametrize("page", ["README.md", *sorted(p.name for p in DOCS.glob("*.md"))])
def test_relative_links_and_images_exist(page):
    path = ROOT / page if page == "README.md" else DOCS / page
    for target in re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", path.read_text()):
        if "://" not in target:
            assert (path.parent / target).exists(), f"{page}: {target}"


# The study configurations the docs show, with the folder each says it is saved in (the
# scene paths in them are relative to that folder).
STUDY_EXAMPLES = [("README.md", ROOT), ("docs/references-and-studies.md", ROOT / "configs")]


@pytest.mark.parametrize("page, folder", STUDY_EXAMPLES)
def test_study_configurations_shown_are_valid(page, folder):
    """What `mcrt compare CONFIG --check` does on each study TOML a page shows, saved where
    the page says: a newcomer who copies it gets a study that runs (the reference page's
    once named a baseline that was not one of its samplers)."""
    import tomllib

    from mcrt.analysis.study.checks import check_config
    from mcrt.analysis.study.config import parse_config

    blocks = re.findall(r"^```toml\n(.*?)^```", (ROOT / page).read_text(), re.S | re.M)
    studies = [tomllib.loads(b) for b in blocks if "[[scenes]]" in b]
    assert studies, page
    for data in studies:
        check_config(parse_config(data, base_dir=folder))


def test_every_study_key_is_documented_in_full_toml():
    """docs/references-and-studies.md says every key of a study configuration is documented
    in configs/full.toml's header."""
    from mcrt.analysis.study import config

    documented = set()
    for line in (ROOT / "configs/full.toml").read_text().splitlines():
        if re.match(r"#   \S", line):  # "#   name, description      shown in the report"
            keys = line[4:].split("  ")[0]
            documented |= {key.strip("[] ") for key in keys.split(",")}
    assert documented >= config._TOP_KEYS, config._TOP_KEYS - documented


@pytest.mark.parametrize("page", ["README.md", *sorted(p.name for p in DOCS.glob("*.md"))])
def test_repository_paths_named_exist(page):
    """A path of this repository a page names in passing (`mcrt/core/stats.py`,
    `benchmarks/...py`, `configs/quick.toml`) exists; placeholders in capitals (NAME, KEY) and
    paths under another root (`~/.cache/mcrt/...`, `/home/me/mcrt/...`) are not such paths."""
    path = ROOT / page if page == "README.md" else DOCS / page
    roots = "benchmarks|scripts|tests|mcrt|configs|scenes|docs"
    for named in re.findall(rf"(?<![\w/.~-])(?:{roots})/[\w./-]*\w", path.read_text()):
        if not re.search(r"(?<![a-z])[A-Z]{3,}(?![a-z])", named):
            assert (ROOT / named).exists(), f"{page}: {named}"


def test_plan_printed_in_the_docs_is_what_mcrt_plan_prints(monkeypatch, capsys):
    """The `$ mcrt plan SCENE` transcripts of the docs are the command's output, word for word
    (the plan is deterministic and takes well under a second)."""
    from mcrt.cli import main

    monkeypatch.chdir(ROOT)
    shown = [(page.name, command, output) for page in sorted(DOCS.glob("*.md"))
             for command, output in re.findall(r"^\$ mcrt (plan [^\n]*)\n(.*?)^```",
                                               page.read_text(), re.S | re.M)]
    assert shown
    for page, command, output in shown:
        assert main(["-q", *command.split()]) == 0
        assert capsys.readouterr().out == output, f"{page}: mcrt {command}"
