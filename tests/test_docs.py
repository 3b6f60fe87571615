"""The documentation (README.md, docs/, mkdocs.yml) stays true to the code it describes.

`make test` also builds the site with `mkdocs build --strict` (broken links and anchors); these
checks need no build: the generated configuration reference is current, every page is in the nav,
and every project path the pages name exists.
"""

from __future__ import annotations

import functools
import importlib.util
import os
import re
from pathlib import Path

import markdown
import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"


def _generator():
    spec = importlib.util.spec_from_file_location("gen_config_reference", DOCS / "gen_config_reference.py")
    module = importlib.util.module_from_spec(spec)  # type: ignore[arg-type]
    spec.loader.exec_module(module)  # type: ignore[union-attr]
    return module


def _pages() -> list[Path]:
    """The documentation's own pages (not the results printouts docs/results/files links to)."""
    pages = DOCS.rglob("*.md")
    return sorted(p for p in pages if not p.relative_to(DOCS).as_posix().startswith("results/files"))


def test_the_configuration_reference_is_generated_from_the_current_models() -> None:
    generator = _generator()
    assert not generator.stale(), (
        f"{generator.stale()} stale: run .venv/bin/python docs/gen_config_reference.py"
    )
    assert len(generator.render()) > 10  # the index and a page per section


def test_the_vehicle_reference_is_generated_from_the_shipped_files() -> None:
    spec = importlib.util.spec_from_file_location("gen_vehicle_reference", DOCS / "gen_vehicle_reference.py")
    module = importlib.util.module_from_spec(spec)  # type: ignore[arg-type]
    spec.loader.exec_module(module)  # type: ignore[union-attr]
    assert not module.stale(), "stale: run .venv/bin/python docs/gen_vehicle_reference.py"
    assert all(f"`{name}`" in module.render() for name in ("nigel", "f1tenth", "bmw320i"))


def test_the_configuration_reference_covers_every_key_with_its_default_and_description() -> None:
    from activelearn.config import CampaignConfig, ModelConfig, PoolConfig, SafetyConfig, TuningConfig

    pages = _generator().render()
    for section, model in (("pool", PoolConfig), ("model", ModelConfig), ("safety", SafetyConfig),
                           ("tuning", TuningConfig), ("", CampaignConfig)):  # fmt: skip
        if section:
            table = pages[f"configuration/{section}.md"].split(f"# [{section}]", 1)[1].split("\n## ", 1)[0]
            assert f"[`[{section}]`](configuration/{section}.md)" in pages["configuration.md"]
        else:
            table = pages["configuration.md"].split("## Top level", 1)[1]
        for name in model.model_fields:
            assert f"| `{name}`<br>" in table, (section, name)
    lines = "\n".join(pages.values()).splitlines()
    kl = next(line for line in lines if line.startswith("| `kl_samples`<br>"))
    assert "`1`" in kl and "weight draws per step for the Monte Carlo KL" in kl  # Field(description=...)
    seed = next(line for line in lines if line.startswith("| `seed`<br>"))
    assert "in [0, 2**32)" in seed  # Field(ge=0, lt=2**32)
    arena = next(line for line in lines if line.startswith("| `arena`<br>"))
    assert "*required*" in arena


def test_every_config_field_has_a_description() -> None:
    """Every key of the reference has its description column filled: each field of each model reachable
    from CampaignConfig (as the page walks them), and of every other model in activelearn.config
    (the tuning space's `Range`, a section not wired in yet)."""
    from activelearn.config.base import _Section

    def subclasses(cls: type) -> list[type]:
        return [s for sub in cls.__subclasses__() for s in (sub, *subclasses(sub))]

    models = _generator().config_models()
    own = [m for m in subclasses(_Section) if m.__module__.startswith("activelearn.config.")]
    models += [m for m in own if m not in models]
    missing = [
        f"{model.__name__}.{name}"
        for model in models
        for name, field in model.model_fields.items()
        if not (field.description or "").strip()
    ]
    assert not missing, f"config fields without Field(description=...): {', '.join(missing)}"
    assert len(models) > 15


def test_every_page_is_in_the_nav_and_every_nav_entry_is_a_page() -> None:
    nav = re.findall(r":\s*([\w./-]+\.md)\s*$", (ROOT / "mkdocs.yml").read_text(), re.M)
    pages = {p.relative_to(DOCS).as_posix() for p in _pages()}
    assert set(nav) - {"results/files/model_selection.md"} == pages
    assert len(nav) == len(set(nav))


def test_the_readme_is_a_front_door() -> None:
    readme = (ROOT / "README.md").read_text()
    assert len(readme.splitlines()) <= 160
    assert "make demo" in readme and "make test" in readme
    for link in re.findall(r"\]\((docs/[^)#]+)", readme):
        assert (ROOT / link).is_file(), link


@pytest.mark.parametrize("page", [ROOT / "README.md", *_pages()], ids=lambda p: str(p.relative_to(ROOT)))
def test_every_project_path_a_page_names_exists(page: Path) -> None:
    """`experiments/...`, `activelearn/...`, `simulator/...` and `tests/...` in code spans are real files
    or folders (placeholders like <name> and globs are skipped)."""
    text = page.read_text()
    named = re.findall(r"`((?:experiments|activelearn|simulator|tests|docs)/[^`\s]*)`", text)
    named += re.findall(r"\]\((files/[^)#\s]+)", text)  # results pages link printouts and figures
    for path in named:
        path = path.rstrip(".,;:)")
        if any(c in path for c in "<>*{}…"):
            continue
        base = page.parent if path.startswith("files/") else ROOT
        assert (base / path).exists(), path


def _paragraphs(text: str) -> list[str]:
    """The plain paragraphs of a Markdown page: runs of lines between blank lines, outside fenced code,
    that are not headings, list items, tables, quotes, admonitions, HTML, images or the indented
    lines that continue a list item or an admonition. A paragraph right before a `text` block is left
    out too: its sentence may go on in the block (a formula)."""
    blocks: list[list[str]] = []
    block: list[str] = []
    fenced = False
    for line in [*text.splitlines(), ""]:
        if line.lstrip().startswith(("```", "~~~")):
            if not fenced and block:
                blocks.append(block)
            if not fenced and blocks and line.strip() in ("```text", "~~~text"):
                blocks.pop()  # the sentence goes on in the formula below
            fenced, block = not fenced, []
            continue
        if fenced:
            continue
        if line.strip():
            block.append(line)
            continue
        if block:
            blocks.append(block)
        block = []
    skip = re.compile(r"(#|[-*+] |\d+[.)] |\||>|!!!|\?\?\?|<|\s|!\[)")
    return ["\n".join(b) for b in blocks if not skip.match(b[0])]


def test_paragraph_detection_skips_what_is_not_prose() -> None:
    page = (
        "# Title\n\nA sentence.\n\nCut off mid\nsentence\n\n- a list\n- item\n\n| a | b |\n|---|---|\n\n"
        "```bash\nmake demo\n```\n\nThe commands:\n\n![a figure](files/x.png)\n\n!!! note\n    body\n\n"
        "With the draws,\n\n```text\nC = (C⁻¹ + P)⁻¹\n```\n\nstore `x` (a fragment).\n"
    )
    paragraphs = ["A sentence.", "Cut off mid\nsentence", "The commands:", "store `x` (a fragment)."]
    assert _paragraphs(page) == paragraphs


@pytest.mark.parametrize("page", _pages(), ids=lambda p: str(p.relative_to(ROOT)))
def test_every_paragraph_ends_with_a_full_stop(page: Path) -> None:
    """A paragraph cut mid-sentence (an edit that lost its end) fails here: each ends with `.`, `?` or
    `!` (closing brackets, quotes and emphasis after it allowed), or `:` where it introduces what
    follows (a list, a table, a code block), and starts as a sentence does (not in lower case)."""
    cut = [p for p in _paragraphs(page.read_text()) if not re.search(r"[.?!:][)\]*_`\"'”’]*$", p.rstrip())]
    assert not cut, "paragraphs without a full stop:\n\n" + "\n\n".join(cut)
    # and none starts in the middle of a sentence (a stray fragment of a cut one)
    fragments = [p for p in _paragraphs(page.read_text()) if p[0].islower()]
    assert not fragments, "paragraphs that start mid-sentence:\n\n" + "\n\n".join(fragments)


@pytest.mark.parametrize("page", _pages(), ids=lambda p: str(p.relative_to(ROOT)))
def test_every_image_a_page_shows_is_a_file_of_the_site(page: Path) -> None:
    """An image path must name a file under docs/ (the site serves nothing else; docs/results/files is
    the results folder, linked in), so a repository path like `../../experiments/...` or a missing
    file fails here rather than as a broken picture."""
    text = page.read_text()
    images = re.findall(r"!\[[^\]]*\]\(([^)\s]+)", text) + re.findall(r"<img[^>]+src=\"([^\"]+)\"", text)
    for image in images:
        assert not re.match(r"[a-z]+:", image), f"{image}: an image from outside the site"
        target = Path(os.path.normpath(page.parent / image.split("#")[0]))
        assert target.is_relative_to(DOCS), f"{image}: outside docs/"
        assert target.is_file(), f"{image}: no such file"


@pytest.mark.parametrize("page", _pages(), ids=lambda p: str(p.relative_to(ROOT)))
def test_every_nested_list_is_indented_four_spaces(page: Path) -> None:
    """Python-Markdown (mkdocs) nests a list item only at 4 spaces per level: one at 2 renders flat,
    as a sibling of the item it belongs to (40 items did, session 38). Fenced code is not prose."""
    fenced, flat = False, []
    for number, line in enumerate(page.read_text().splitlines(), start=1):
        if line.lstrip().startswith("```"):
            fenced = not fenced
        elif not fenced and re.match(r"(  |      )([-*]|\d+\.) ", line):
            flat.append(f"{number}: {line.strip()[:60]}")
    assert not flat, "list items indented 2 (or 6) spaces, which render flat:\n" + "\n".join(flat)


@functools.cache
def _markdown_extensions() -> tuple[list[str], dict[str, dict]]:
    """mkdocs.yml's markdown extensions and their options, read once for every page."""
    extensions, configs = [], {}
    for entry in yaml.safe_load((ROOT / "mkdocs.yml").read_text())["markdown_extensions"]:
        name, options = next(iter(entry.items())) if isinstance(entry, dict) else (entry, {})
        extensions.append(name)
        configs[name] = options or {}
    return extensions, configs


def _render(text: str) -> str:
    """The page's HTML as mkdocs renders it (Python-Markdown with mkdocs.yml's extensions), code removed."""
    extensions, configs = _markdown_extensions()
    html = markdown.markdown(text, extensions=extensions, extension_configs=configs)
    return re.sub(r"<pre>.*?</pre>|<code>.*?</code>", "", html, flags=re.S)


def _raw_markup(html: str) -> list[str]:
    """Lines of rendered paragraphs that start as a list item or are a table row: markup shown as text."""
    raw = []
    for paragraph in re.findall(r"<p>(.*?)</p>", html, flags=re.S):
        for line in paragraph.splitlines():
            line = line.strip()
            if re.match(r"([-*+]|\d+\.) ", line) or re.fullmatch(r"\|.*\|", line):
                raw.append(line[:70])
    return raw


def test_raw_markup_detection_finds_what_python_markdown_shows_as_text() -> None:
    broken = "- item\n\n  | a | b |\n  |---|---|\n  | 1 | 2 |\n\n  after the table.\n- next item\n"
    mended = "- item\n\n    | a | b |\n    |---|---|\n    | 1 | 2 |\n\n    after the table.\n\n- next item\n"
    assert _raw_markup(_render(broken)) == ["- next item"]
    assert _raw_markup(_render(mended)) == []
    assert _raw_markup(_render("The guards:\n- one\n- two\n")) == ["- one", "- two"]


@pytest.mark.parametrize("page", _pages(), ids=lambda p: str(p.relative_to(ROOT)))
def test_no_list_item_or_table_row_renders_as_text(page: Path) -> None:
    """Python-Markdown ends a list at a block indented less than 4 spaces under its item, and reads an item
    right after a paragraph (no blank line between) as that paragraph's text: the bullets then show as
    raw '- ' (58 lines on five pages did, session 44). A table row shown as text fails too."""
    raw = _raw_markup(_render(page.read_text()))
    assert not raw, "list items or table rows shown as text:\n" + "\n".join(raw)
