"""The package's structure: one-way layers (import-linter), no import cycles, no private reads across modules."""

from __future__ import annotations

import ast
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "stewart_gym"


def lint_imports(cwd: Path) -> subprocess.CompletedProcess:
    exe = Path(sys.executable).with_name("lint-imports")
    return subprocess.run([str(exe)], cwd=cwd, capture_output=True, text=True, timeout=300,
                          env={"PYTHONPATH": str(cwd), "PATH": "/usr/bin:/bin"})  # fmt: skip


def test_layers_are_kept() -> None:
    out = lint_imports(ROOT)
    assert out.returncode == 0, out.stdout + out.stderr
    assert "1 kept, 0 broken" in out.stdout


def test_a_lower_layer_importing_a_higher_one_breaks_the_contract(tmp_path: Path) -> None:
    """The check is real: a copy of the package whose geometry imports the envs fails it."""
    shutil.copytree(PACKAGE, tmp_path / "stewart_gym", ignore=shutil.ignore_patterns("policies", "__pycache__"))
    shutil.copy(ROOT / "pyproject.toml", tmp_path / "pyproject.toml")
    geometry = tmp_path / "stewart_gym" / "geometry.py"
    geometry.write_text(geometry.read_text() + "\n\ndef _late() -> None:\n    import stewart_gym.envs.ball_env  # noqa\n")
    out = lint_imports(tmp_path)
    assert out.returncode != 0 and "broken" in out.stdout


def _module_imports() -> dict[str, set[str]]:
    """Module → the package modules it imports (anywhere in the file, functions included)."""
    graph: dict[str, set[str]] = {}
    for path in PACKAGE.rglob("*.py"):
        name = ".".join(path.relative_to(ROOT).with_suffix("").parts).removesuffix(".__init__")
        deps: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                deps |= {a.name for a in node.names if a.name.startswith("stewart_gym")}
            elif isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("stewart_gym"):
                deps.add(node.module)
                deps |= {f"{node.module}.{a.name}" for a in node.names}
        graph[name] = deps
    return {m: {d for d in deps if d in graph and d != m} for m, deps in graph.items()}


def test_no_import_cycles() -> None:
    graph = _module_imports()
    graph = {m: {d for d in deps if d != "stewart_gym"} for m, deps in graph.items()}  # the package root re-exports
    state: dict[str, int] = {}
    cycles: list[list[str]] = []

    def visit(m: str, stack: list[str]) -> None:
        state[m] = 1
        for d in sorted(graph[m]):
            if state.get(d) == 1 and not m.startswith(d + "."):  # a package's __init__ importing its submodules is fine
                cycles.append(stack[stack.index(d):] + [d] if d in stack else [m, d])
            elif d not in state:
                visit(d, stack + [d])
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m, [m])
    real = [c for c in cycles if not all(a.startswith(b + ".") or b.startswith(a + ".") for a, b in zip(c, c[1:]))]
    assert not real, real


def test_no_private_attribute_is_read_across_modules() -> None:
    """``x._name`` only on ``self``/``cls``/``super()`` (the pybullet_utils client id is the one exception)."""
    allowed = {("stewart_gym/sim/stewart_sim.py", "_client")}  # BulletClient keeps its server id there
    found = []
    for path in PACKAGE.rglob("*.py"):
        rel = str(path.relative_to(ROOT))
        for node in ast.walk(ast.parse(path.read_text())):
            if (isinstance(node, ast.Attribute) and node.attr.startswith("_") and not node.attr.startswith("__")
                    and not (isinstance(node.value, ast.Name) and node.value.id in ("self", "cls"))
                    and not (isinstance(node.value, ast.Call) and getattr(node.value.func, "id", "") == "super")
                    and (rel, node.attr) not in allowed):  # fmt: skip
                found.append(f"{rel}:{node.lineno} .{node.attr}")
    assert not found, found


@pytest.mark.slow
def test_the_manual_builds_strictly(tmp_path: Path) -> None:
    """mkdocs build --strict: every page builds, every API page resolves, no broken link, tables generated."""
    exe = Path(sys.executable).with_name("mkdocs")
    out = subprocess.run([str(exe), "build", "--strict", "-f", str(ROOT / "docs" / "mkdocs.yml"), "-d",
                          str(tmp_path / "site")], capture_output=True, text=True, timeout=600,
                         env={"PATH": "/usr/bin:/bin", "NO_MKDOCS_2_WARNING": "1", "HOME": str(tmp_path)})  # fmt: skip
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-3000:]
    envs = (tmp_path / "site" / "environments" / "index.html").read_text()
    assert "{{" not in envs and "StewartBallDisturbance-v0" in envs and "previous action" in envs
    assert "inverse_kinematics" in (tmp_path / "site" / "api" / "kinematics" / "index.html").read_text()
    assert not broken_links(tmp_path / "site")


def broken_links(site: Path) -> list[str]:
    """Every link and image of the built site that points inside it to a page, file or anchor that is not there
    (a link checker over the HTML, anchors included)."""
    import html.parser
    from urllib.parse import unquote, urlsplit

    class Collect(html.parser.HTMLParser):
        def __init__(self) -> None:
            super().__init__()
            self.links: list[str] = []
            self.ids: set[str] = set()

        def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
            a = dict(attrs)
            self.ids.update(v for k, v in attrs if k in ("id", "name") and v)
            for key in ("href", "src"):
                if a.get(key) and (tag != "link" or a.get("rel") == "stylesheet"):
                    self.links.append(a[key])

    pages: dict[Path, Collect] = {}
    for page in site.rglob("*.html"):
        parsed = Collect()
        parsed.feed(page.read_text())
        pages[page.resolve()] = parsed
    broken = []
    for page, parsed in pages.items():
        for link in parsed.links:
            parts = urlsplit(link)
            if parts.scheme or parts.netloc or link.startswith(("mailto:", "javascript:", "data:")):
                continue  # outside the site
            path = unquote(parts.path)
            base = site.resolve() if path.startswith("/") else page.parent  # the 404 page links from the root
            target = (base / path.lstrip("/")).resolve() if path else page
            if target.is_dir():
                target = target / "index.html"
            if not target.exists():
                broken.append(f"{page.relative_to(site.resolve())}: {link}")
            elif parts.fragment and target in pages and unquote(parts.fragment) not in pages[target].ids:
                broken.append(f"{page.relative_to(site.resolve())}: {link} (no such anchor)")
    return broken


def test_nothing_cites_documents_that_are_not_shipped() -> None:
    """The code and docs cite facts the docs hold, not the development notes that are not in the repository."""
    hits = [str(p.relative_to(ROOT)) for folder in ("stewart_gym", "docs", "tests", "bench", "train")
            for p in (ROOT / folder).rglob("*") if p.suffix in (".py", ".md", ".yml") and "REFERENCE.md" in p.read_text()
            and p.name != "test_architecture.py"]  # fmt: skip
    assert not hits, hits


def test_readme_is_a_front_door() -> None:
    """At most 120 lines: the two commands, how to call the installed ones, a Python example, one results table
    and links into the manual that all exist."""
    readme = (ROOT / "README.md").read_text()
    assert len(readme.splitlines()) <= 120
    assert "make demo" in readme and "make test" in readme and ".venv/bin/activate" in readme
    assert readme.count("```python") == 1 and readme.count("<!-- headline:start -->") == 1
    links = re.findall(r"\]\((docs/src/[^)#]+)", readme)
    assert len(links) >= 10 and all((ROOT / link).is_file() for link in links), links


def test_the_link_checker_finds_a_missing_page_and_a_missing_anchor(tmp_path: Path) -> None:
    (tmp_path / "a").mkdir()
    (tmp_path / "a" / "index.html").write_text('<h2 id="here">x</h2><a href="../b/">b</a><a href="#here">h</a>'
                                               '<a href="../c/">c</a><a href="../b/#gone">g</a>'
                                               '<a href="https://example.org/x">e</a>')  # fmt: skip
    (tmp_path / "b").mkdir()
    (tmp_path / "b" / "index.html").write_text('<p id="there">y</p><img src="../a/pic.png">')
    assert sorted(broken_links(tmp_path)) == ["a/index.html: ../b/#gone (no such anchor)", "a/index.html: ../c/",
                                              "b/index.html: ../a/pic.png"]  # fmt: skip
