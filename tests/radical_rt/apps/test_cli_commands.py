"""How `radical` finds its subcommands (#18): the engine's own (`process`, `node`) by name, every
other one through the entry points of group ``radical.commands``; a contract command without a
provider, a stale entry point and a provider that fails to import each give one clear line."""

from __future__ import annotations

import ast
import re
import sys
from importlib.metadata import EntryPoint
from pathlib import Path

import pytest

from radical_rt.apps import cli

ROOT = Path(__file__).resolve().parents[3]
UPPER = re.compile(r"\b(replayer|mission|monitors|perf|studies)\.[A-Za-z_]")


def _with_entry_points(monkeypatch, **eps: str) -> None:
    points = [EntryPoint(name, value, cli.GROUP) for name, value in eps.items()]
    monkeypatch.setattr(cli, "entry_points", lambda group: [e for e in points if e.group == group])


def _listed(capsys) -> dict[str, str]:
    with pytest.raises(SystemExit):
        cli.main(["--help"])
    out = capsys.readouterr().out
    return dict(re.findall(r"^    (\w+)\s+(.*)$", out, flags=re.M))


def test_the_installed_entry_points_provide_the_contract_commands():
    """pyproject's [project.entry-points."radical.commands"] as installed (a stale install: run
    `pip install -e .` again)."""
    found = cli.providers()
    assert set(cli.CONTRACT_COMMANDS) | {"export", "allan", "design"} <= set(found)
    assert found["process"].startswith("radical_rt.") and found["node"].startswith("radical_rt.")


def test_a_command_without_provider_is_listed_and_says_so(monkeypatch, capsys):
    _with_entry_points(monkeypatch)  # nothing installed but the engine
    listed = _listed(capsys)
    assert list(listed) == [*cli.CONTRACT_COMMANDS,
                            *(n for n in cli.BUILTIN if n not in cli.CONTRACT_COMMANDS)]
    assert listed["synth"] == "(not installed)" and "batch shell" in listed["process"]
    assert cli.main(["synth", "2006216", "-o", "x.mcap", "--help"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("radical synth: not installed: "), err
    assert "radical.commands" in err[0] and "pip install -e ." in err[0]


def test_an_extension_comes_with_its_help_and_stale_or_broken_ones_say_why(
        monkeypatch, capsys, tmp_path):
    (tmp_path / "radical_ext_ok.py").write_text(
        '"""An extension."""\nHELP = "do a thing"\n\ndef add_arguments(p):\n'
        '    p.add_argument("--n", type=int, default=1)\n\ndef run(args):\n    return args.n\n')
    (tmp_path / "radical_ext_broken.py").write_text("import radical_no_such_dependency\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    _with_entry_points(monkeypatch, thing="radical_ext_ok", gone="radical_ext_gone",
                       broken="radical_ext_broken", process="radical_ext_ok")
    try:
        listed = _listed(capsys)
        assert listed["thing"] == "do a thing"
        assert listed["gone"] == "(not installed)"
        assert listed["broken"].startswith("(unavailable: No module named")
        assert "batch shell" in listed["process"]  # the engine's own command is kept
        assert cli.main(["thing", "--n", "7"]) == 7
        for name, says in (("gone", "not installed: its module radical_ext_gone is missing"),
                           ("broken", "unavailable: No module named 'radical_no_such")):
            assert cli.main([name]) == 2
            err = capsys.readouterr().err.strip()
            assert err.startswith(f"radical {name}: {says}"), err
        with pytest.raises(SystemExit):  # a real command still refuses unknown arguments
            cli.main(["thing", "--bogus"])
        assert "unrecognized arguments: --bogus" in capsys.readouterr().err
    finally:
        for m in ("radical_ext_ok", "radical_ext_broken"):
            sys.modules.pop(m, None)


def test_the_engine_names_no_upper_package_even_by_string():
    """No string in radical_rt (docstrings included) is a dotted name in replayer, mission,
    monitors, perf or studies: nothing can be imported upward by name (import-linter sees only
    import statements)."""
    hits = []
    for path in sorted((ROOT / "radical_rt").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Constant) and isinstance(node.value, str):
                hits += [f"{path.relative_to(ROOT)}:{node.lineno}: {m.group(0)}…"
                         for m in UPPER.finditer(node.value)]
    assert hits == []


def test_a_command_line_imports_only_its_command():
    """`radical process ...` builds only the process sub-parser: no other subcommand's module (nor
    the tools built on the engine) is imported; its parse is the full parser's."""
    import subprocess

    code = ("import sys; from radical_rt.apps import cli; p = cli.build_parser('process'); "
            "a = p.parse_args(['process', 'x.mcap', '--quiet']); "
            "print(a.handler.__module__, a.inputs, a.quiet); "
            "print(sorted(m for m in sys.modules if m.split('.')[0] in "
            "('replayer', 'monitors', 'mission') or m.startswith('radical_rt.apps.')))")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                       cwd=ROOT)
    assert r.returncode == 0, r.stderr
    first, mods = r.stdout.splitlines()
    assert first == "radical_rt.apps.batch ['x.mcap'] True"
    assert mods == "['radical_rt.apps.batch', 'radical_rt.apps.cli']"
    full = cli.build_parser().parse_args(["process", "x.mcap", "--quiet"])
    assert (full.handler.__module__, full.inputs, full.quiet) == ("radical_rt.apps.batch",
                                                                 ["x.mcap"], True)
