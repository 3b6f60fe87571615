"""The documentation (README.md, docs/, mkdocs.yml) stays true to the code it describes.

`make test` also builds the site with `mkdocs build --strict` (broken links and anchors); these
checks need no build: the generated configuration reference is current, every page is in the nav,
and every project path the pages name exists.
"""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path

import pytest

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
    committed = (DOCS / "reference" / "configuration.md").read_text()
    assert committed == generator.render(), (
        "docs/reference/configuration.md is stale: run .venv/bin/python docs/gen_config_reference.py"
    )


def test_the_configuration_reference_covers_every_key_with_its_default_and_description() -> None:
    from activelearn.config import CampaignConfig, ModelConfig, PoolConfig, SafetyConfig, TuningConfig

    page = _generator().render()
    for section, model in (("pool", PoolConfig), ("model", ModelConfig), ("safety", SafetyConfig),
                           ("tuning", TuningConfig), ("", CampaignConfig)):  # fmt: skip
        title = f"## [{section}]" if section else "## Top level"
        table = page.split(title, 1)[1].split("\n## ", 1)[0]
        for name in model.model_fields:
            assert f"| `{name}` |" in table, (section, name)
    kl = next(line for line in page.splitlines() if line.startswith("| `kl_samples` |"))
    assert "`1`" in kl and "weight draws per step for the Monte Carlo KL" in kl  # Field(description=...)
    seed = next(line for line in page.splitlines() if line.startswith("| `seed` |"))
    assert "in [0, 2**32)" in seed  # Field(ge=0, lt=2**32)
    arena = next(line for line in page.splitlines() if line.startswith("| `arena` |"))
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
