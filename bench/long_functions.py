"""Functions longer than a limit (default 80 lines) in the C++ core, the bindings and the Python
package, longest first: the style check of issue 18 ("short functions").

    python bench/long_functions.py [--limit 80] [paths ...]

Python functions come from the ast (nested functions counted on their own and inside their
parent); C++ functions are definitions opening at column 0 (the code base does not indent
namespaces), measured to their closing brace at column 0. Prints `lines path:line name` and the
count.
"""

from __future__ import annotations

import argparse
import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_PATHS = ("cpp", "python/forestslam")
_CPP_SKIP = re.compile(
    r"^(namespace|struct|class|enum|union|template|using|typedef|#|//|/\*|\}|extern)"
)


def python_functions(path: Path) -> list[tuple[int, int, str]]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            out.append((node.end_lineno - node.lineno + 1, node.lineno, node.name))
    return out


def cpp_functions(path: Path) -> list[tuple[int, int, str]]:
    lines = path.read_text(encoding="utf-8").splitlines()
    out, i = [], 0
    while i < len(lines):
        line = lines[i]
        if line[:1].strip() and not _CPP_SKIP.match(line) and "(" in line and ";" not in line:
            name = re.findall(r"([\w:~]+)\s*\(", line)
            j = i
            while j < len(lines) and "{" not in lines[j] and ";" not in lines[j]:
                j += 1
            if j < len(lines) and "{" in lines[j]:
                k = j
                while k < len(lines) and not lines[k].startswith("}"):
                    k += 1
                out.append((k - i + 1, i + 1, name[0] if name else "?"))
                i = k
        i += 1
    return out


def long_functions(paths: list[str], limit: int) -> list[tuple[int, str, str]]:
    found = []
    for top in paths:
        top_path = ROOT / top
        for path in [top_path] if top_path.is_file() else sorted(top_path.rglob("*")):
            if path.suffix == ".py":
                funcs = python_functions(path)
            elif path.suffix in (".cpp", ".hpp"):
                funcs = cpp_functions(path)
            else:
                continue
            rel = path.relative_to(ROOT)
            found += [(n, f"{rel}:{line}", name) for n, line, name in funcs if n > limit]
    return sorted(found, reverse=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("paths", nargs="*", default=list(DEFAULT_PATHS))
    parser.add_argument("--limit", type=int, default=80)
    args = parser.parse_args()
    found = long_functions(args.paths, args.limit)
    for n, where, name in found:
        print(f"{n:5d} {where} {name}")
    print(f"{len(found)} functions longer than {args.limit} lines")


if __name__ == "__main__":
    main()
