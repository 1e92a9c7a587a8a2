"""The house: layers importing one way, no circles, small modules, one home per fact, a wheel of the
product only. Read from the source with `ast`, deferred imports included."""

from __future__ import annotations

import ast
import fnmatch
import re
import shutil
import subprocess
import sys
import tokenize
import zipfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PACKAGE = REPO / "pd_analyze"
LAYERS = ("model", "capture", "protocol", "analysis", "output", "cli")  # each imports only those before it
MAX_LINES = 450


def _modules() -> dict[str, Path]:
    out = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = path.relative_to(REPO).with_suffix("").parts
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        out[name] = path
    return out


MODULES = _modules()


def _imports(name: str, path: Path) -> set[str]:
    """Modules of the project `name` imports anywhere in its file (top level or inside functions)."""
    package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")[:len(package.split(".")) - node.level + 1]
                base = ".".join([*parts, base] if base else parts)
            for alias in node.names:
                full = f"{base}.{alias.name}"
                found.add(full if full in MODULES else base)
    return found


GRAPH = {name: _imports(name, path) for name, path in MODULES.items()}


def _layer(name: str) -> int | None:
    parts = name.split(".")
    return LAYERS.index(parts[1]) if len(parts) > 1 and parts[1] in LAYERS else None


def test_imports_flow_down_the_layers() -> None:
    upward = [(name, dep) for name, deps in GRAPH.items() for dep in deps
              if _layer(name) is not None and _layer(dep) is not None and _layer(dep) > _layer(name)]
    assert upward == []


def test_no_import_circle_deferred_imports_included() -> None:
    done: set[str] = set()
    cycles = []

    def visit(name: str, stack: list[str]) -> None:
        stack.append(name)
        for dep in sorted(GRAPH[name] & set(MODULES)):
            if dep in stack:
                cycles.append([*stack[stack.index(dep):], dep])
            elif dep not in done:
                visit(dep, stack)
        stack.pop()
        done.add(name)

    for name in MODULES:
        if name not in done:
            visit(name, [])
    assert cycles == []


def test_the_product_never_imports_the_development_tools() -> None:
    assert [name for name, deps in GRAPH.items() if any(d.split(".")[0] in ("devtools", "tests") for d in deps)] == []


def test_modules_are_small_or_say_why() -> None:
    """A module past MAX_LINES names why in a comment among its first lines ('# Longer than ...')."""
    big = []
    for name, path in MODULES.items():
        lines = path.read_text().splitlines()
        if len(lines) > MAX_LINES and not any(line.startswith("# Longer than") for line in lines[:30]):
            big.append((name, len(lines)))
    assert big == []


def _decimal_numbers(path: Path) -> set[str]:
    """Decimal integer literals of a module's code (hex masks such as 0xF0 are not a restated limit)."""
    with path.open("rb") as f:
        return {tok.string for tok in tokenize.tokenize(f.readline) if tok.type == tokenize.NUMBER
                and tok.string.isdigit()}


def test_the_record_limit_has_one_home() -> None:
    """240, and the 234 elements and 39 x 6 + 4 = 238 bytes that follow from it, are the profile data's."""
    stated = {str(p.relative_to(REPO)): sorted(_decimal_numbers(p) & {"240", "234", "238"})
              for p in MODULES.values()}
    assert {k: v for k, v in stated.items() if v} == {}


def _code_of(path: Path) -> str:
    """The module's code without comments and docstrings: where a fact would be restated."""
    tree = ast.parse(path.read_text())
    for node in ast.walk(tree):
        body = getattr(node, "body", None)
        if isinstance(body, list) and body and isinstance(body[0], ast.Expr) \
                and isinstance(body[0].value, ast.Constant) and isinstance(body[0].value.value, str):
            body[0].value.value = ""
    return ast.unparse(tree)


@pytest.mark.parametrize(("pattern", "home", "what"), [
    (r"0x8100|0x88A8|0x9100|\\x81\\x00|\\x88\\xa8|\\x91\\x00", "pd_analyze/model/values.py", "the VLAN TPIDs"),
    (r"'malformed', 'pnio_error'|'ok', 'nak'", "pd_analyze/model/verdicts.py", "the verdict list"),
    (r"\bChecker\(", "pd_analyze/protocol/profidrive_checks.py", "how a Checker is built"),
    (r"del self\.\w+\[next\(iter|popitem\(last=False\)", "pd_analyze/model/capped.py", "evicting the oldest"),
])
def test_each_fact_has_one_home(pattern: str, home: str, what: str) -> None:
    elsewhere = [str(path.relative_to(REPO)) for path in MODULES.values()
                 if str(path.relative_to(REPO)) != home and re.search(pattern, _code_of(path))]
    assert elsewhere == [], f"{what} is stated outside {home}"


def test_built_wheel_holds_only_the_product(tmp_path: Path) -> None:
    # built from a copy of the sources: setuptools reuses a build/ directory left in the repository, whose
    # stale modules (one since renamed) would go into the wheel
    src = tmp_path / "src"
    shutil.copytree(PACKAGE, src / "pd_analyze", ignore=shutil.ignore_patterns("__pycache__"))
    for name in ("pyproject.toml", "README.md", "LICENSE"):
        shutil.copy(REPO / name, src / name)
    # -v: the build backend's own output, where setuptools announces what it will stop supporting
    r = subprocess.run([sys.executable, "-m", "pip", "wheel", str(src), "--no-deps", "-v", "-w", str(tmp_path)],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    assert [line for line in (r.stdout + r.stderr).splitlines() if "DeprecationWarning" in line] == []
    (wheel,) = tmp_path.glob("pd_analyze-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    metadata = zipfile.ZipFile(wheel).read(f"{wheel.name.split('-py3')[0]}.dist-info/METADATA").decode()
    assert "License-Expression: MIT" in metadata.splitlines() and "License-File: LICENSE" in metadata.splitlines()
    assert f"{wheel.name.split('-py3')[0]}.dist-info/licenses/LICENSE" in names
    assert {n.split("/")[0] for n in names} == {"pd_analyze", f"{wheel.name.split('-py3')[0]}.dist-info"}
    shipped = {n for n in names if n.startswith("pd_analyze/")}
    assert shipped == {str(p.relative_to(REPO)) for p in PACKAGE.rglob("*")
                       if p.is_file() and p.suffix in (".py", ".toml", ".css", ".js") and "__pycache__" not in p.parts}
    assert not [n for n in names if re.search(r"synth|fuzz|hostile|devtools|tests/", n)]



# The top level as the design lays it out (README, "Architecture"): anything else there is stray output
# (a `--help/` directory holding copies of the samples was once committed by a merge)
TOP_LEVEL = frozenset({"pyproject.toml", "pd_analyze", "tests", "sample_pcaps", "notebooks", "README.md", "docs",
                       "devtools", "benchmarks", ".ci"})
LICENCE = re.compile(r"(LICEN[CS]E|COPYING)(\.(md|txt))?")


def _stray(names: list[str], ignored: list[str]) -> list[str]:
    """The names that are neither the design's entries, a dotfile, a licence nor ignored (.gitignore patterns)."""
    return sorted(n for n in names if n not in TOP_LEVEL and not n.startswith(".") and not LICENCE.fullmatch(n)
                  and not any(fnmatch.fnmatch(n, p.strip("/")) for p in ignored))


def test_the_top_level_holds_only_the_designs_entries() -> None:
    """What a checkout (or a developer's work tree, less what .gitignore names: the venv, build output) holds at
    the top: the design's entries, dotfiles and a licence."""
    ignored = [line.strip() for line in (REPO / ".gitignore").read_text().splitlines()
               if line.strip() and not line.startswith("#")]
    assert _stray([p.name for p in REPO.iterdir()], ignored) == []
    assert _stray(["--help", "LICENSE", "pd_analyze.egg-info", "out", "report.html"], ignored) == ["--help",
                                                                                                   "report.html"]


def _docstrings(tree: ast.AST) -> set[int]:
    return {id(node.body[0].value) for node in ast.walk(tree)
            if isinstance(getattr(node, "body", None), list) and node.body and isinstance(node.body[0], ast.Expr)
            and isinstance(node.body[0].value, ast.Constant)}


def _unguarded_shared(source: str) -> list[int]:
    """Lines of a test module that name ../shared themselves (a "shared" path part in a string that is not a
    docstring) or build a path inside it (`SHARED_CAPTURES / name`) instead of asking tests.support, whose
    shared_capture() skips with the reason when the directory is absent and shared_captures() finds none."""
    tree = ast.parse(source)
    docs = _docstrings(tree)
    lines = []
    for node in ast.walk(tree):
        names_it = isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in docs \
            and re.search(r"(^|[/\\])shared([/\\]|$)", node.value)
        joins_it = isinstance(node, ast.BinOp) and isinstance(node.op, ast.Div) \
            and (getattr(node.left, "id", None) or getattr(node.left, "attr", None)) in ("SHARED_CAPTURES", "SHARED")
        if names_it or joins_it:
            lines.append(node.lineno)
    return sorted(lines)


def test_no_test_reaches_the_shared_captures_without_the_guard() -> None:
    """A clone of the project alone has no ../shared: every test passes or skips with its reason there."""
    found = {str(p.relative_to(REPO)): _unguarded_shared(p.read_text()) for p in sorted((REPO / "tests").glob("*.py"))
             if p.name not in ("support.py", "test_architecture.py")}  # the guard's home; this check's examples
    assert {k: v for k, v in found.items() if v} == {}
    # the check finds the forms it is for
    assert _unguarded_shared('p = ROOT.parent / "shared" / "captures" / "x.pcap"\n') == [1]
    assert _unguarded_shared('x = 1\nopen("../shared/captures/x.pcap")\n') == [2]
    assert _unguarded_shared('def f():\n    """from ../shared/captures"""\n    return SHARED_CAPTURES / "x"\n') == [3]
    assert _unguarded_shared('p = shared_capture("x.pcap")\nq = "shared hosts"\n') == []


def _third_party_imports() -> dict[str, set[str]]:
    """Top-level names of the packages pd_analyze imports, anywhere (deferred imports too), by module."""
    found: dict[str, set[str]] = {}
    for name, path in MODULES.items():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                tops = {alias.name.split(".")[0] for alias in node.names}
            elif isinstance(node, ast.ImportFrom) and not node.level and node.module:
                tops = {node.module.split(".")[0]}
            else:
                continue
            for top in tops - set(sys.stdlib_module_names) - {"pd_analyze"}:
                found.setdefault(top, set()).add(name)
    return found


def test_every_package_the_product_imports_is_declared() -> None:
    """numpy once came only through pandas: each package pd_analyze imports is a dependency of its own (dask,
    imported by analysis.distributed alone, is the `dask` extra)."""
    import tomllib

    def name(requirement: str) -> str:  # "dask[dataframe]>=2024.1" -> "dask"
        return re.match(r"[A-Za-z0-9._-]+", requirement).group(0).lower()  # type: ignore[union-attr]

    project = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
    declared = {name(r) for r in project["dependencies"]}
    extras = {extra: {name(r) for r in reqs} for extra, reqs in project["optional-dependencies"].items()}
    imported = _third_party_imports()
    assert sorted(imported) == ["click", "dask", "dpkt", "matplotlib", "numpy", "pandas", "pyarrow", "tqdm"]
    assert sorted(set(imported) - declared) == ["dask"]
    assert "dask" in extras["dask"] and imported["dask"] == {"pd_analyze.analysis.distributed"}
