"""``--help``'s option tables: typer's rich layout, but with every name of an option whole.

Typer lays an option out in four name columns (long names joined by commas, short ones, ``--no-…`` ones, short
``--no-…`` ones) beside its type and help. Those columns do not wrap, so at 80 columns, piped or in a narrow
terminal, rich cut them to fit: ``--both-directio…``, ``--car,--car-cal…``, and env var names in the help column
(``RACER_ENVS_PER_WORK…``). Here an option's names go one under another in one column, which leaves the help column
room for the longest env var name, and every column folds rather than cut whatever still does not fit.

Typer has no setting for this layout: :func:`use_racer_help_layout` puts :func:`print_options_panel` in place of
``typer.rich_utils._print_options_panel``, the function typer's ``rich_format_help`` calls for each panel.
``tests/test_cli_frictions.py`` renders every command's help at 80 columns, so a typer that stops calling it fails
there.
"""

from __future__ import annotations

from typing import Any

import typer.rich_utils as rich_utils
from rich import box
from rich.columns import Columns
from rich.console import Console, RenderableType
from rich.panel import Panel
from rich.table import Table
from rich.text import Text
from typer.core import TyperArgument, TyperOption


def _names(param: TyperOption | TyperArgument) -> Text:
    """The option's names, one per line: its long names (the first with its short ones), then its ``--no-…`` ones.
    An argument: its display name."""
    if isinstance(param, TyperArgument):
        name = param.display_name_raw + ("..." if param.metavar is None and param.nargs != 1 else "")
        return rich_utils.highlighter(name)
    lines = _name_lines(param.opts, rich_utils.highlighter)
    lines += _name_lines(param.secondary_opts, rich_utils.negative_highlighter)
    return Text("\n").join(lines)


def _name_lines(opts: list[str], highlight: Any) -> list[Text]:
    """Long names one per line, the short ones after the first (``--verbose, -v``)."""
    long = [o for o in opts if o.startswith("--")]
    short = [o for o in opts if not o.startswith("--")]
    lines = long or short[:1]
    if long and short:
        lines = [", ".join([long[0], *short]), *long[1:]]
    return [highlight(line) for line in lines]


def _type(param: TyperOption | TyperArgument, ctx: Any) -> Text:
    """``<int range> [x>=1]``: the value's type and range, as typer shows them."""
    text = Text(style=rich_utils.STYLE_TYPES, overflow="fold")
    shown = param.display_type_rich(ctx=ctx)
    if shown is not None:
        text.append(shown)
    number_range = param._get_number_range_help_str()
    if number_range:
        text.append(rich_utils.RANGE_STRING.format(number_range))
    return rich_utils.types_highlighter(text)


def _help(param: TyperOption | TyperArgument, ctx: Any, markup_mode: rich_utils.MarkupModeStrict) -> Columns:
    """Typer's help cell (the help, ``[env var: …]``, ``[default: …]``), its parts folding rather than cut: rich's
    Columns, which lays them out, ends a part that does not fit with "…" (``RACER_ENVS_PER_WORK…``)."""
    cell = rich_utils._get_parameter_help(param=param, ctx=ctx, markup_mode=markup_mode)
    for part in cell.renderables:
        if isinstance(part, Text):
            part.overflow = "fold"
    return cell


def print_options_panel(
    *,
    name: str,
    params: list[TyperOption] | list[TyperArgument],
    ctx: Any,
    markup_mode: rich_utils.MarkupModeStrict,
    console: Console,
) -> None:
    """One panel of options or arguments (typer's ``_print_options_panel``, its signature kept): a ``*`` column if
    any is required, then names, type, help."""
    if not params:
        return
    required = any(param.required for param in params)
    table = Table(
        highlight=True,
        show_header=False,
        expand=True,
        box=getattr(box, rich_utils.STYLE_OPTIONS_TABLE_BOX, None),
        show_lines=rich_utils.STYLE_OPTIONS_TABLE_SHOW_LINES,
        leading=rich_utils.STYLE_OPTIONS_TABLE_LEADING,
        border_style=rich_utils.STYLE_OPTIONS_TABLE_BORDER_STYLE,
        row_styles=rich_utils.STYLE_OPTIONS_TABLE_ROW_STYLES,
        pad_edge=rich_utils.STYLE_OPTIONS_TABLE_PAD_EDGE,
        padding=rich_utils.STYLE_OPTIONS_TABLE_PADDING,
    )
    if required:
        table.add_column(no_wrap=True)
    # The names do not wrap, so that rich narrows the type and help columns, not them, in a narrow terminal. Those two
    # fold rather than end in rich's "…": what does not fit on a line goes on the next, whole.
    table.add_column(no_wrap=True)
    table.add_column(overflow="fold")
    table.add_column(overflow="fold")
    for param in params:
        star = Text(rich_utils.REQUIRED_SHORT_STRING, style=rich_utils.STYLE_REQUIRED_SHORT) if param.required else ""
        row: list[RenderableType] = [_names(param), _type(param, ctx), _help(param, ctx, markup_mode)]
        table.add_row(*([star, *row] if required else row))
    border = rich_utils.STYLE_OPTIONS_PANEL_BORDER
    console.print(Panel(table, border_style=border, title=name, title_align=rich_utils.ALIGN_OPTIONS_PANEL))


def use_racer_help_layout() -> None:
    """Make typer's rich help print option panels with :func:`print_options_panel`."""
    rich_utils._print_options_panel = print_options_panel
