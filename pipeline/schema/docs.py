"""Docs generation: the Markdown column tables and rules of ``docs/tables.md``, derived from the table specs.

``tests/test_schema.py`` checks that ``docs/tables.md`` still matches what these functions produce.
"""
from __future__ import annotations

from pipeline.schema.specs import TABLES

__all__ = ["columns_markdown", "table_markdown"]


def columns_markdown(kind: str) -> str:
    """Markdown table of the columns of table kind `kind` (used in ``docs/tables.md``)."""
    lines = ["| column | type | unit | required | nullable | values | meaning |",
             "|---|---|---|---|---|---|---|"]
    def cell(text: str) -> str:
        return text.replace("|", "\\|") or "–"

    for c in TABLES[kind].columns:
        lines.append(f"| `{c.name}` | {c.type_label} | {cell(c.unit)} | {'yes' if c.required else 'no'} "
                     f"| {'yes' if c.nullable else 'no'} | {cell(c.value_rule)} | {cell(c.meaning)} |")
    return "\n".join(lines) + "\n"


def table_markdown(kind: str) -> str:
    """Columns and rules of table kind `kind` as Markdown."""
    rules = "\n".join(f"- {r}" for r in TABLES[kind].rules)
    return f"{columns_markdown(kind)}\nRules:\n\n{rules}\n"
