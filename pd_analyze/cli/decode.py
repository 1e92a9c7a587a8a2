"""The reference commands: `decode` (a parameter block given as hex), `profiles` (the vendor limits side by
side, with their sources) and `fields` (the field registry)."""

from __future__ import annotations

import sys

import click

from pd_analyze.cli.base import EXIT_OK, checker_for, main, profile_option, text_style
from pd_analyze.model.fields import FIELDS
from pd_analyze.output import dump
from pd_analyze.output.decode import decode, parse_hex
from pd_analyze.protocol import profiles

DECODE_EXAMPLES = """\b
Examples:
  pd-analyze decode "01 01 01 02 10 01 03 C4 00 00 10 03 07 D0 00 00" --request
  pd-analyze decode 0101010142011234 --response --for-request 01010101100103c40000
  pd-analyze decode "5F 00 2F 0A 01 01 01 01 10 00 00 2F 00 00" --dpv1
  pd-analyze decode "..." --request --profile sinamics --format json
  xxd -p record.bin | pd-analyze decode - --response
"""


@main.command("decode", epilog=DECODE_EXAMPLES)
@click.argument("hex_text", nargs=-1, required=True, metavar="HEX")
@click.option("--request", "side", flag_value="request", help="The bytes are a parameter request.")
@click.option("--response", "side", flag_value="response", help="The bytes are a parameter response.")
@click.option("--dpv1", is_flag=True, help="A DP-V1 header (0x5E read / 0x5F write, slot, index, length) "
                                           "precedes the block.")
@click.option("--for-request", "for_request", metavar="HEX",
              help="The request a response answers, to label its blocks P<pnu>[<sub>].")
@click.option("--format", "fmt", type=click.Choice(["text", "json"]), default="text", show_default=True)
@profile_option
def decode_command(hex_text: tuple[str, ...], side: str | None, dpv1: bool, for_request: str | None,
                   fmt: str, profile: str) -> None:
    """Decode a raw PROFIdrive parameter block given as hex (spaces or not); - reads the hex from standard input."""
    checker = checker_for(profile)
    text = " ".join(hex_text)
    if hex_text == ("-",):  # as every command's -: the hex from standard input (line breaks are spaces)
        text = sys.stdin.buffer.read().decode("ascii", "replace")  # bytes that are no hex: said by parse_hex
    try:
        data = parse_hex(text)
        request = parse_hex(for_request) if for_request else None
        result = decode(data, None if side is None else side == "response", checker, dpv1, request)
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="HEX") from None
    if fmt == "json":
        click.echo(dump.decoded_json(result.sections, result.findings))
    else:
        kind = "response" if result.response else "request"
        click.echo(f"PROFIdrive parameter {kind}, {len(data)} bytes, profile {profile}")
        click.echo(dump.decoded_text(result.sections, result.findings, text_style(sys.stdout.isatty())))
    sys.exit(EXIT_OK)


@main.command("profiles")
@click.argument("names", nargs=-1, metavar="[NAME|FILE.toml]...")
@click.option("--format", "fmt", type=click.Choice(["text", "markdown"]), default="text", show_default=True)
def profiles_command(names: tuple[str, ...], fmt: str) -> None:
    """Print the limits of the vendor profiles side by side, with their sources."""
    try:
        chosen = [profiles.load(n) for n in (names or sorted(profiles.packaged(), key=_profile_order))]
    except profiles.ProfileError as exc:
        raise click.BadParameter(str(exc), param_hint="NAME") from None
    click.echo(profiles_table(chosen, fmt))


def _profile_order(name: str) -> tuple[int, str]:
    return (0 if name == profiles.DEFAULT else 1, name)


def profiles_table(chosen: list[profiles.Profile], fmt: str) -> str:
    keys = [k for k in profiles.LIMIT_KEYS if any(p.limits_for(k) for p in chosen)]
    header = ["limit"] + [p.name for p in chosen]
    rows = [[k] + [" / ".join(lim.text() for lim in p.limits_for(k)) or "-" for p in chosen] for k in keys]
    lines = []
    if fmt == "markdown":
        lines.append("| " + " | ".join(header) + " |")
        lines.append("|" + "---|" * len(header))
        lines += ["| " + " | ".join(row) + " |" for row in rows]
    else:
        widths = [max(len(r[i]) for r in [header, *rows]) for i in range(len(header))]
        lines.append("  ".join(h.ljust(w) for h, w in zip(header, widths, strict=True)))
        lines += ["  ".join(c.ljust(w) for c, w in zip(row, widths, strict=True)) for row in rows]
    lines.append("")
    lines.append("Sources:")
    for p in chosen:
        lines.append(f"  {p.name}: {p.title}. {p.description}")
        for lim in p.limits:
            lines.append(f"    {lim.key} = {lim.text()}  <- {lim.source}")
        if p.tolerate:
            lines += [f"    tolerates: {profiles.TOLERATIONS[t]}" for t in sorted(p.tolerate)]
        if p.error_texts:
            lines.append(f"    vendor error texts: {', '.join(f'{k:#04x}' for k in p.error_texts)}")
        if p.pnu_names:
            shown = ", ".join(f"P{k}" for k in sorted(p.pnu_names)[:8]) + (", ..." if len(p.pnu_names) > 8 else "")
            lines.append(f"    parameter names: {len(p.pnu_names)} ({shown})")
        lines += p.ids.listing() if p.ids is not None else []
    return "\n".join(lines)


@main.command("fields")
@click.option("--format", "fmt", type=click.Choice(["text", "markdown"]), default="text", show_default=True)
def fields_command(fmt: str) -> None:
    """List every field name of the registry with its type, tshark name and description."""
    if fmt == "markdown":
        click.echo("| Field | Type | tshark | Description |\n|---|---|---|---|")
    for f in FIELDS.values():
        if fmt == "markdown":
            click.echo(f"| `{f.name}` | {f.type} | {f'`{f.tshark}`' if f.tshark else ''} | {f.description} |")
        else:
            click.echo(f"{f.name:<24} {f.type:<6} {f.tshark or '-':<44} {f.description}")
