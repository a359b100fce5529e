"""How big the repository is, and how tangled: the before/after table of a restructuring.

    python scripts/size_report.py                  # the working tree (tracked and untracked, not ignored)
    python scripts/size_report.py --rev main       # a commit, read from git objects (no checkout needed)
    python scripts/size_report.py --before main    # two columns: main, then the working tree

It prints, as markdown: lines of Python and shell per top-level folder, files in ``models/``, lines of each
doc (``README.md``, ``docs/*.md``) and the import cycles among the project's modules. The import graph is
static (``ast``), over every ``import`` of a module of the packages below, lazy ones inside functions
included: a lazy import still ties two modules together. Stdlib only; run it from the repository root.
"""

from __future__ import annotations

import argparse
import ast
import subprocess
from collections.abc import Iterator
from pathlib import Path

PACKAGES = ("runtime", "hil_sim", "trainer", "export")
CODE_SUFFIXES = (".py", ".sh")

Tree = dict[str, bytes]  # path -> contents


def _git(*args: str) -> bytes:
    return subprocess.run(["git", *args], check=True, capture_output=True).stdout


def read_tree(rev: str | None) -> Tree:
    """Every file of ``rev`` (a commit), or of the working tree when None (tracked and untracked files,
    not the ignored ones)."""
    if rev is None:
        names = _git("ls-files", "-z", "--cached", "--others", "--exclude-standard").decode().split("\0")
        return {n: Path(n).read_bytes() for n in names if n and Path(n).is_file()}
    names = [n for n in _git("ls-tree", "-r", "-z", "--name-only", rev).decode().split("\0") if n]
    batch = "".join(f"{rev}:{n}\n" for n in names).encode()
    out = subprocess.run(["git", "cat-file", "--batch"], input=batch, check=True, capture_output=True).stdout
    tree, pos = {}, 0
    for name in names:  # each answer: "<sha> <type> <size>\n<contents>\n"
        header_end = out.index(b"\n", pos)
        size = int(out[pos:header_end].split()[2])
        tree[name] = out[header_end + 1 : header_end + 1 + size]
        pos = header_end + 2 + size
    return tree


def _lines(data: bytes) -> int:
    return data.count(b"\n") + (0 if data.endswith(b"\n") or not data else 1)


def code_lines(tree: Tree) -> dict[str, int]:
    """Lines of .py and .sh per top-level folder ("." for files at the root)."""
    sizes: dict[str, int] = {}
    for name, data in tree.items():
        if name.endswith(CODE_SUFFIXES):
            top = name.split("/", 1)[0] if "/" in name else "."
            sizes[top] = sizes.get(top, 0) + _lines(data)
    return sizes


def model_files(tree: Tree) -> tuple[int, int]:
    """Files under models/, and how many of them are code."""
    names = [n for n in tree if n.startswith("models/")]
    return len(names), sum(n.endswith(CODE_SUFFIXES) for n in names)


def _is_doc(name: str) -> bool:
    return name == "README.md" or (name.startswith("docs/") and name.endswith(".md"))


def doc_lines(tree: Tree) -> dict[str, int]:
    return {n: _lines(d) for n, d in tree.items() if _is_doc(n)}


def _module_name(path: str) -> str:
    parts = path[: -len(".py")].split("/")
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports(name: str, is_package: bool, source: bytes, modules: set[str]) -> Iterator[str]:
    """The project's modules that the source imports (relative imports resolved). ``from pkg import mod``
    counts as importing ``pkg.mod`` alone: the parent package's ``__init__`` is not an edge."""
    package = name if is_package else name.rpartition(".")[0]
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            yield from (alias.name for alias in node.names if alias.name in modules)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.rsplit(".", node.level - 1)[0] if node.level > 1 else package
                base = f"{anchor}.{base}" if base else anchor
            for alias in node.names:
                target = f"{base}.{alias.name}"
                if target in modules:
                    yield target
                elif base in modules:
                    yield base


def import_graph(tree: Tree) -> dict[str, set[str]]:
    """Module -> the project's modules it imports, over PACKAGES."""
    sources = {n: d for n, d in tree.items() if n.endswith(".py") and n.split("/", 1)[0] in PACKAGES}
    modules = {_module_name(n): (n, d) for n, d in sources.items()}
    names = set(modules)
    return {
        mod: set(_imports(mod, path.endswith("__init__.py"), data, names)) - {mod}
        for mod, (path, data) in modules.items()
    }


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return sorted(found)


def report(tree: Tree) -> list[dict[str, object]]:
    """One column of the table, as sections (code, models/, docs, imports) of row label -> value."""
    code = {f"lines (.py+.sh) {top}/": n for top, n in sorted(code_lines(tree).items())}
    files, code_files = model_files(tree)
    docs = {f"lines {doc}": n for doc, n in sorted(doc_lines(tree).items())}
    found = cycles(import_graph(tree))
    imports: dict[str, object] = {"import cycles": len(found)}
    imports.update({f"cycle {i + 1}": " <-> ".join(c) for i, c in enumerate(found)})
    return [code, {"files in models/ (code)": f"{files} ({code_files})"}, docs, imports]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--rev", help="measure this commit instead of the working tree")
    p.add_argument("--before", help="a second column: this commit, measured first")
    args = p.parse_args()
    columns = {args.rev or "working tree": report(read_tree(args.rev))}
    if args.before:
        columns = {args.before: report(read_tree(args.before)), **columns}
    print("| | " + " | ".join(columns) + " |")
    print("| --- |" + " --- |" * len(columns))
    for section in zip(*columns.values(), strict=True):
        for label in dict.fromkeys(label for rows in section for label in rows):
            print(f"| {label} | " + " | ".join(str(rows.get(label, "-")) for rows in section) + " |")


if __name__ == "__main__":
    main()
