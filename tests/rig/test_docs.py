from pathlib import Path

from rig.joints import joint_table_markdown

DOCS = Path(__file__).resolve().parents[2] / "docs"


def test_joint_table_in_docs_matches_code():
    text = (DOCS / "joints.md").read_text()
    assert joint_table_markdown() in text
