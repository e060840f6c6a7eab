"""The project's house rules, read from its own files: FreeFEM's command-line options are read
in one place (freefem/parameters.idp), the README stays a five-minute read, and no test reads
the committed results tree. Pure Python, no FreeFEM: each rule names the file and line that
breaks it. The layer rules of the harness's imports are tests/test_layers.py."""

from __future__ import annotations

import ast
import re
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).parents[1]
FREEFEM = ROOT / "freefem"
HARNESS = ROOT / "harness"
TESTS = Path(__file__).parent
# Every knob in one place, as FreeFEM's own libraries keep theirs (STYLE.md: ffddm_parameters.idp).
PARAMETERS = FREEFEM / "parameters.idp"
# args.idp defines the readers themselves: the only other file that may touch ARGV.
READERS = FREEFEM / "args.idp"
README_LINES = 150  # the limit of a five-minute read (the README had 144 when it was last cut)

# A read of an option: the readers of args.idp (argReal, argInt, argString; parameters.idp's
# argOf<type> aliases of them), FreeFEM's getARGV.idp, or the command line itself.
CALL = re.compile(r"\b(argReal|argInt|argString|argOf\w*|getARGV)\s*\(")
OPTION_READ = re.compile(CALL.pattern + r"|\bARGV\b")


def option_reads(text: str) -> list[int]:
    """1-based lines of `text` (FreeFEM source) that read a command-line option; comments
    (`// ...` to the end of the line) do not count."""
    return [i for i, line in enumerate(text.splitlines(), 1) if OPTION_READ.search(line.split("//", 1)[0])]


def test_the_option_rule_sees_a_read_and_skips_a_comment():
    text = ('string partsDir = argString("-parallel.parts", "");\n'
            '// argString("-in.a.comment", "") is no read\n'
            "for (int i = 0; i < ARGV.n; ++i) n += 1;\n"
            "real argRealish = 1; // a name, not a call\n")
    assert option_reads(text) == [1, 3]


def test_every_freefem_option_is_read_in_parameters_idp():
    """Every .idp/.edp of freefem/ (materials included) reads no option but parameters.idp;
    args.idp may only define the readers."""
    sources = sorted(p for p in FREEFEM.rglob("*") if p.suffix in (".idp", ".edp"))
    assert PARAMETERS in sources and len(sources) > 20
    found = []
    for path in sources:
        if path == PARAMETERS:
            continue
        lines = path.read_text().splitlines()
        for i in option_reads(path.read_text()):
            line = lines[i - 1].lstrip()
            if path == READERS and (line.startswith("func ") or not CALL.search(line)):
                continue  # a reader's own definition, or its body's loop over ARGV
            found.append(f"{path.relative_to(ROOT)}:{i}: {lines[i - 1].strip()}")
    assert not found, "options read outside freefem/parameters.idp:\n" + "\n".join(found)
    assert option_reads(PARAMETERS.read_text())  # the rule reads the right file


def test_the_scripts_the_harness_writes_read_no_option():
    """The main script of a run is written by harness/run/script.py (with the material regions'
    definitions of harness/scene/): no string of the harness writes a read of an option into it."""
    found = []
    for path in sorted(HARNESS.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Constant) and isinstance(node.value, str) and option_reads(node.value):
                found.append(f"{path.relative_to(ROOT)}:{node.lineno}: {node.value.strip()[:80]}")
    assert not found, "FreeFEM option reads written by the harness:\n" + "\n".join(found)


def test_the_readme_is_a_five_minute_read():
    lines = (ROOT / "README.md").read_text().splitlines()
    assert len(lines) <= README_LINES, (f"README.md has {len(lines)} lines, at most {README_LINES}: move the "
                                        "details to docs/ and link them")


# No test reads results/: the committed results are what `make` studies last wrote, and a test
# compares with tests/gold/ (pinned by `make gold`) or computes its own reference.


# Paths into results/ that are not reads of a result, each with why: (test file, expression).
NOT_READS = {
    # A study run from another folder must leave the checkout's results/ alone: the test looks
    # for its own probe scene's folder there, and removes it if a regression wrote one.
    ("test_results_location.py", "REPO / 'results' / name"),
}


@dataclass
class ResultsReads:
    """Where a test's code reaches into the repository's results/ tree. Paths are followed
    symbolically from the repository root (`Path(__file__).parents[1]`, harness.core.layout's
    REPO) through names and `/`; a path built on anything else (pytest's tmp_path) is the
    test's own. A bare "results/..." string is read from the folder the suite runs in, the
    repository's root."""

    path: Path
    root: Path = ROOT
    found: list[str] = field(default_factory=list)

    def scan(self) -> list[str]:
        tree = ast.parse(self.path.read_text())
        docstrings = {id(n.body[0].value) for n in ast.walk(tree)
                      if isinstance(n, (ast.Module, ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef))
                      and n.body and isinstance(n.body[0], ast.Expr) and isinstance(n.body[0].value, ast.Constant)}
        roots = {a.asname or a.name: () for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)
                 and n.module == "harness.core.layout" for a in n.names if a.name == "REPO"}
        module = self.bindings(tree.body, dict(roots))
        self.visit(tree, module, docstrings)
        return self.found

    def bindings(self, body: list[ast.stmt], env: dict[str, tuple[str, ...]]) -> dict[str, tuple[str, ...]]:
        """Names bound in `body` (this scope's statements, in order) to a path under the repository."""
        for stmt in body:
            for node in ast.walk(stmt):
                if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)) and node is not stmt:
                    continue
                if isinstance(node, ast.Assign) and len(node.targets) == 1 and isinstance(node.targets[0], ast.Name):
                    parts = self.parts(node.value, env)
                    if parts is None:
                        env.pop(node.targets[0].id, None)
                    else:
                        env[node.targets[0].id] = parts
        return env

    def visit(self, tree: ast.AST, env: dict[str, tuple[str, ...]], docstrings: set[int]) -> None:
        for node in ast.iter_child_nodes(tree):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                self.visit(node, self.bindings(node.body, dict(env)), docstrings)
                continue
            if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Div):
                parts = self.parts(node, env)
                if parts and parts[0] == "results":
                    if (self.path.name, ast.unparse(node)) not in NOT_READS:
                        self.found.append(f"{self.path.name}:{node.lineno}: {ast.unparse(node)}")
                    continue
            if (isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in docstrings
                    and re.match(r"(\./)?results/", node.value)):
                self.found.append(f"{self.path.name}:{node.lineno}: {node.value!r}")
            self.visit(node, env, docstrings)

    def parts(self, node: ast.AST, env: dict[str, tuple[str, ...]]) -> tuple[str, ...] | None:
        """The path `node` stands for, relative to the repository's root; None when it is not
        one under the repository (or cannot be told)."""
        if isinstance(node, ast.Name):
            return env.get(node.id)
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "Path" and node.args:
            first = node.args[0]
            if isinstance(first, ast.Name) and first.id == "__file__":
                return tuple(self.path.relative_to(self.root).parts)
            if isinstance(first, ast.Constant) and isinstance(first.value, str) and not first.value.startswith("/"):
                return tuple(p for p in first.value.split("/") if p not in ("", "."))  # the suite runs from the root
            return None
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr in ("resolve", "absolute"):
            return self.parts(node.func.value, env)
        if isinstance(node, ast.Attribute) and node.attr == "parent":
            inner = self.parts(node.value, env)
            return inner[:-1] if inner else None
        if (isinstance(node, ast.Subscript) and isinstance(node.value, ast.Attribute) and node.value.attr == "parents"
                and isinstance(node.slice, ast.Constant) and isinstance(node.slice.value, int)):
            inner = self.parts(node.value.value, env)
            up = node.slice.value + 1
            return inner[:-up] if inner is not None and len(inner) >= up else None
        if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Div):
            left = self.parts(node.left, env)
            if left is None:
                return None
            if not (isinstance(node.right, ast.Constant) and isinstance(node.right.value, str)):
                return left + ("*",)  # a name's value: somewhere below `left`
            return left + tuple(p for p in node.right.value.split("/") if p not in ("", "."))
        return None


def results_reads(path: Path) -> list[str]:
    return ResultsReads(path).scan()


def test_the_results_rule_tells_the_repository_from_a_tmp_dir(tmp_path):
    """The rule flags the repository's results/ by any of its roots, not a tmp dir's, nor a
    name rebound to one, nor a docstring."""
    probe = tmp_path / "tests" / "test_probe.py"  # tmp_path stands in for the repository
    probe.parent.mkdir()
    probe.write_text('"""A docstring may name results/paper/summary.json."""\n'
                     "from pathlib import Path\n"
                     "from harness.core.layout import REPO\n"
                     "ROOT = Path(__file__).parents[1]\n"
                     "HERE = Path(__file__).resolve().parent\n"
                     "def test_a(tmp_path):\n"
                     "    ours = tmp_path / 'results' / 'paper'\n"
                     "    gold = ROOT / 'tests' / 'gold' / 'scaling.csv'\n"
                     "    bad = REPO / 'results' / 'paper3d' / 'summary.json'\n"
                     "    worse = HERE.parent / 'results/paper'\n"
                     "    ROOT = tmp_path\n"
                     "    fine = ROOT / 'results'\n"
                     "    also = Path('results/cost/scaling.csv')\n"
                     "    too = Path('results') / 'paper' / 'summary.json'\n"
                     "    cases = Path('cases') / 'paper.toml'\n")
    found = ResultsReads(probe, root=tmp_path).scan()
    assert [line.split(":")[1] for line in found] == ["9", "10", "13", "14"], found


def test_no_test_reads_the_committed_results():
    tests = sorted(TESTS.glob("*.py"))
    assert Path(__file__) in tests and len(tests) > 30
    found = [line for path in tests for line in results_reads(path)]
    assert not found, "tests that read results/ (compare with tests/gold/ instead):\n" + "\n".join(found)


def test_the_layer_rules_stay_tested():
    """The import-graph rules of the harness's layers (tests/test_layers.py) are kept: each of
    its three tests is still there."""
    tree = ast.parse((TESTS / "test_layers.py").read_text())
    tests = {n.name for n in tree.body if isinstance(n, ast.FunctionDef) and n.name.startswith("test_")}
    assert {"test_every_module_lives_in_a_layer_folder_or_is_an_entry_point",
            "test_no_module_imports_from_a_layer_above_its_own", "test_the_import_graph_has_no_cycle"} <= tests, tests
