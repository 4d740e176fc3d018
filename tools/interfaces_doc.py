"""Generate the parts of docs/interfaces.md that the code defines, or check that they are current.

Usage::

    .venv/bin/python tools/interfaces_doc.py           # rewrite the generated sections
    .venv/bin/python tools/interfaces_doc.py --check   # exit 1, naming the section, if one is stale

Three sections are generated, each between ``<!-- generated:NAME -->`` and
``<!-- /generated:NAME -->``; the text outside the markers is written by hand:

* ``topics``: the bag layout's topics and types (:mod:`reachset_ros.bags.messages`);
* ``messages``: the ``reachset_msgs`` definitions (``msg_defs/msg``, ``msg_defs/srv``);
* ``commands``: every ``reachset`` subcommand's ``--help`` (the argparse parser itself).
"""
import argparse
import os
import re
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
DOC = REPO / "docs" / "interfaces.md"
sys.path.insert(0, str(REPO))


def topics_section():
    from reachset_ros.bags import messages as m
    rows = [("JOINT_STATES", "JOINT_STATE_TYPE"), ("PLANT_INPUT", "PLANT_INPUT_TYPE"),
            ("REFERENCE_TOPIC", "REFERENCE_TYPE"), ("ESTIMATE_TOPIC", "ESTIMATE_TYPE"),
            ("STATUS_TOPIC", "STATUS_TYPE"), ("SAFE_STOP_TOPIC", "SAFE_STOP_TYPE"),
            ("FAULT_ONSET_TOPIC", "FAULT_ONSET_TYPE"), ("BRAKE_TOPIC", "BRAKE_TYPE")]
    out = ["| topic | type | constant in `reachset_ros.bags` |", "|---|---|---|"]
    for topic, typ in rows:
        out.append(f"| `{getattr(m, topic)}` | `{getattr(m, typ)}` | `{topic}` |")
    out.append(f"| `{m.DIAGNOSTICS_TOPIC}` | `diagnostic_msgs/msg/DiagnosticArray` | `DIAGNOSTICS_TOPIC` |")
    return "\n".join(out)


def messages_section():
    out = []
    for kind in ("msg", "srv"):
        for p in sorted((REPO / "msg_defs" / kind).glob(f"*.{kind}")):
            out += [f"#### `reachset_msgs/{kind}/{p.stem}`", "", "```"]
            out += [line.rstrip() for line in p.read_text().strip().splitlines()]
            out += ["```", ""]
    return "\n".join(out).rstrip()


def commands_section():
    os.environ["COLUMNS"] = "100"
    from reachset_ros.cli import build_parser
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    out = []
    for name, sp in sub.choices.items():
        text = sp.format_help().replace(os.path.basename(sys.argv[0]), "reachset")
        out += [f"#### `reachset {name}`", "", "```"]
        out += [line.rstrip() for line in text.strip().splitlines()]
        out += ["```", ""]
    return "\n".join(out).rstrip()


SECTIONS = {"topics": topics_section, "messages": messages_section, "commands": commands_section}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="exit 1 if a generated section is stale")
    a = ap.parse_args(argv)
    text = DOC.read_text()
    new = text
    for name, make in SECTIONS.items():
        pat = re.compile(rf"(<!-- generated:{name} -->\n).*?(<!-- /generated:{name} -->)", re.S)
        if not pat.search(new):
            print(f"{DOC}: no <!-- generated:{name} --> section", file=sys.stderr)
            return 1
        body = make()
        new = pat.sub(lambda mo: mo.group(1) + body + "\n" + mo.group(2), new)
        if a.check and pat.search(text).group(0) != pat.search(new).group(0):
            print(f"{DOC}: section '{name}' is stale; run tools/interfaces_doc.py", file=sys.stderr)
            return 1
    if not a.check and new != text:
        DOC.write_text(new)
    return 0


if __name__ == "__main__":
    sys.exit(main())
