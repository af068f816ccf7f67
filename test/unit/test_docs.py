"""The docs stay true: the parameter tables equal the schema; the contract names every topic and subcommand."""

import argparse

from attitude_sil.cli import build_parser
from attitude_sil.core.sim.params import parameters_markdown
from attitude_sil.ros.contract import RECORDED_TOPICS
from conftest import ROOT

DOCS = ROOT / "docs"


def test_parameters_doc_is_generated_from_the_schema():
    # after a schema change: make docs
    assert parameters_markdown() in (DOCS / "parameters.md").read_text()


def test_architecture_names_every_topic_and_subcommand():
    text = (DOCS / "architecture.md").read_text()
    for topic in RECORDED_TOPICS:
        assert f"`{topic}`" in text, topic
    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    for name in sub.choices:
        assert f"`{name}" in text, name


def test_readme_and_docs_point_inside_the_repository():
    for path in [ROOT / "README.md", *DOCS.glob("*.md"), *(ROOT / "bench").glob("*.*")]:
        text = path.read_text()
        assert "../shared" not in text and "DESIGN.md" not in text, path


def test_every_relative_link_of_the_docs_resolves():
    # the broken-link check: README, the guides and the bench notes link files that exist
    import re

    pages = [ROOT / "README.md", ROOT / "bench" / "README.md", *DOCS.glob("*.md")]
    broken = []
    for page in pages:
        for target in re.findall(r"\]\(([^)\s]+)\)", page.read_text()):
            if re.match(r"[a-z]+:", target) or target.startswith("#"):
                continue
            path = (page.parent / target.split("#")[0]).resolve()
            if not path.exists():
                broken.append(f"{page.relative_to(ROOT)} -> {target}")
    assert not broken, "broken links:\n" + "\n".join(broken)


def test_readme_is_a_tour_that_links_every_guide():
    text = (ROOT / "README.md").read_text()
    assert len(text.splitlines()) <= 200
    assert text.startswith("# attitude_sil\n\n```bash\nmake run") and "make test" in text.split("```")[1]
    for guide in DOCS.glob("*.md"):
        assert f"(docs/{guide.name})" in text, guide.name
