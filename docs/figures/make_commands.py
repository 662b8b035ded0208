"""Write docs/commands.md from the command line's own parsers: every command, its everyday options
with the first sentence of their help, and its advanced options by name.

    python docs/figures/make_commands.py [--out docs/commands.md]

tests/test_docs.py checks that the page lists every option of every command."""

import argparse
import re
from pathlib import Path

from creference_bayes.cli.main import build_parser

INTRO = """# Commands

Every `creference` command with its options, generated from the command line's own parsers by
[`figures/make_commands.py`](figures/make_commands.py). `creference CMD --help` gives each option's
whole help, its default and the advanced options' help; what a message means:
[messages](messages.md); how the commands fit together: [the user guide](user_guide.md).
"""

#: What a table of options cannot say, by command.
NOTES = {
    "estimate": """Progress bars appear on standard error for the steps that can take more than a few seconds
        (the paper presets' restarts, the sampler), only when it is a terminal. The model options of
        `--option KEY=VALUE`: [user guide](user_guide.md#model-options).""",
    "plot": """Without `--scene` the result's scene is found: a batch folder's copy, the path `estimate
        --out` recorded (`scene_path`, relative to the result), then a file of the result's `scene`
        name next to the result, in the current folder or among the shipped scenes; the first of
        these that is the result's scene is used, and one passed over (another photo's scene of the
        same name, or an edited copy) is named in a `warning:` line. A scene that is not the one the
        result came from (other targets, another image size, or edited contents) is refused.""",
}


def commands(parser, prefix=""):
    """(name, parser) of every command and sub-command, in the order --help lists them."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield prefix + name, sub
                yield from commands(sub, prefix + name + " ")


def first_sentence(text: str) -> str:
    text = " ".join((text or "").split()).replace("%(default)s", "…").replace("%%", "%")
    text = re.split(r"(?<=[.;:])\s|\s\(", text, maxsplit=1)[0].rstrip(".;:")
    return text.replace("|", "\\|")


def usage_of(action) -> str:
    if not action.option_strings:
        return f"`{action.metavar or action.dest}`"
    name = max(action.option_strings, key=len)
    if action.nargs == 0:
        return f"`{name}`"
    metavar = action.metavar or action.dest.upper()
    return f"`{name} {metavar if isinstance(metavar, str) else ' '.join(metavar)}`"


def page() -> str:
    out = [INTRO]
    for name, sub in commands(build_parser()):
        out += [f"## {name}", "", first_sentence(sub.description or "") + ".", ""]
        rows = []
        for group in sub._action_groups:
            for action in group._group_actions:
                if action.help == argparse.SUPPRESS or isinstance(action, (argparse._HelpAction,
                                                                            argparse._SubParsersAction)):
                    continue
                mark = " (advanced)" if "advanced" in (group.title or "") else ""
                rows.append(f"| {usage_of(action)}{mark} | {first_sentence(action.help)} |")
        if rows:
            out += ["| argument or option | what it is |", "|---|---|", *rows, ""]
        else:
            out += [f"`creference {name} --help` lists its commands.", ""]
        if name in NOTES:
            out += [" ".join(NOTES[name].split()), ""]
    return "\n".join(out).rstrip("\n") + "\n"


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default=str(Path(__file__).resolve().parents[1] / "commands.md"))
    args = ap.parse_args()
    Path(args.out).write_text(page())
    print(f"wrote {args.out}")
