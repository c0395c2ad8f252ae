"""``python -m config [--readme README.md]``: print or rewrite the settings reference."""

import argparse
import sys
from pathlib import Path

from config.settings import README_BEGIN, README_END, settings_reference_markdown


def main() -> int:
    parser = argparse.ArgumentParser(prog="python -m config", description=__doc__)
    parser.add_argument("--readme", type=Path, help="rewrite the reference section of this file")
    args = parser.parse_args()
    table = settings_reference_markdown()
    if args.readme is None:
        print(table)
        return 0
    text = args.readme.read_text(encoding="utf-8")
    head, found_begin, rest = text.partition(README_BEGIN)
    _, found_end, tail = rest.partition(README_END)
    if not (found_begin and found_end):
        print(f"{args.readme}: reference markers not found", file=sys.stderr)
        return 1
    args.readme.write_text(f"{head}{README_BEGIN}\n{table}\n{README_END}{tail}", encoding="utf-8")
    return 0


sys.exit(main())
