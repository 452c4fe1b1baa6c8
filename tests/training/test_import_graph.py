"""The training package's layering, read from the source (ast, nothing imported): no import circle, no import
of a training module hidden inside a function, no pipeline module importing the lab (training/experiments),
and the C++ tools run from training/tools.py only.

    /usr/bin/python3 tests/training/test_import_graph.py      # prints the graph (module: what it imports)
"""
import ast
import pathlib
import sys

REPO = pathlib.Path(__file__).resolve().parents[2]
TRAINING = REPO / "training"
# Modules that run other programs than the C++ tools: sox (music, engine_tempo) and python lanes (engine_suite).
SUBPROCESS_OK = {"training.tools", "training.eval.music", "training.eval.engine_tempo", "training.eval.engine_suite"}


def modules() -> dict[str, pathlib.Path]:
  out = {}
  for path in sorted(TRAINING.rglob("*.py")):
    parts = path.relative_to(REPO).with_suffix("").parts
    name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
    out[name] = path
  return out


def _resolve(name: str, mods) -> str | None:
  while name and name not in mods:
    name = name.rpartition(".")[0]
  return name or None


def imports(mods) -> dict[str, tuple[set[str], set[str]]]:
  """module -> (training modules imported at module level, those imported inside a function)."""
  graph = {}
  for name, path in mods.items():
    tree = ast.parse(path.read_text())
    nested = {id(n) for f in ast.walk(tree) if isinstance(f, (ast.FunctionDef, ast.AsyncFunctionDef))
              for n in ast.walk(f)}
    top, inner = set(), set()
    for node in ast.walk(tree):
      if isinstance(node, ast.Import):
        targets = [_resolve(a.name, mods) for a in node.names if a.name.startswith("training")]
      elif isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("training"):
        # `from training.x import y`: the submodule x.y when there is one, else x
        targets = [_resolve(f"{node.module}.{a.name}", mods) for a in node.names]
      else:
        continue
      (inner if id(node) in nested else top).update(t for t in targets if t and t != name)
    graph[name] = (top, inner - top)
  return graph


def circles(graph) -> list[list[str]]:
  """Strongly connected components of more than one module (Tarjan), over both kinds of import."""
  index, low, stack, on, out = {}, {}, [], set(), []

  def visit(v):
    index[v] = low[v] = len(index)
    stack.append(v)
    on.add(v)
    for w in sorted(graph[v][0] | graph[v][1]):
      if w not in index:
        visit(w)
        low[v] = min(low[v], low[w])
      elif w in on:
        low[v] = min(low[v], index[w])
    if low[v] == index[v]:
      comp = []
      while True:
        w = stack.pop()
        on.discard(w)
        comp.append(w)
        if w == v:
          break
      if len(comp) > 1:
        out.append(sorted(comp))

  for v in sorted(graph):
    if v not in index:
      visit(v)
  return out


def test_no_import_circle_and_no_import_inside_a_function():
  graph = imports(modules())
  assert circles(graph) == []
  hidden = {m: sorted(inner) for m, (_, inner) in graph.items() if inner}
  assert hidden == {}


def test_no_pipeline_module_imports_the_lab():
  graph = imports(modules())
  lab = {m for m in graph if m.startswith("training.experiments")}
  users = {m: sorted((top | inner) & lab) for m, (top, inner) in graph.items() if m not in lab and (top | inner) & lab}
  assert users == {}


def test_only_tools_runs_the_cpp_tools():
  for name, path in modules().items():
    text = path.read_text()
    if name != "training.tools":
      assert "DANCE_BUILD_DIR\"" not in text and "DANCE_BUILD_DIR'" not in text, name  # the build dir: tools.build_dir
      assert "/bin/" not in text.replace("/usr/bin/python3", "").replace(".venv/bin/", ""), name
    tree = ast.parse(text)
    uses = any(isinstance(n, ast.Import) and any(a.name == "subprocess" for a in n.names) for n in ast.walk(tree))
    assert not uses or name in SUBPROCESS_OK, f"{name} runs a subprocess: C++ tools go through training.tools"


if __name__ == "__main__":
  g = imports(modules())
  for m in sorted(g):
    top, inner = g[m]
    if top or inner:
      print(f"{m}: " + ", ".join(sorted(top) + [f"{x} (in a function)" for x in sorted(inner)]))
  print(f"\n{len(g)} modules; import circles: {circles(g) or 'none'}", file=sys.stderr)
