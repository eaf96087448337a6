"""Run every benchmark in bench/ in turn (quick settings where a script offers them) and
print their tables; copy the figures into docs/performance.md."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent


def main() -> int:
    failed = []
    for script in sorted(HERE.glob("bench_*.py")):
        print(f"\n## {script.name}\n", flush=True)
        args = [sys.executable, str(script)]
        if "--quick" in script.read_text():
            args.append("--quick")
        if subprocess.run(args).returncode != 0:
            failed.append(script.name)
    if failed:
        print(f"\nfailed: {', '.join(failed)}", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
