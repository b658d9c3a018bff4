"""The documentation's commands run, and the pages stay what docs/architecture.md says they are.

Markers, on the line right before a fence in README.md or docs/*.md:

- ``<!-- runnable -->``: the fence runs as written (bash, or a Python snippet) and must
  exit 0: the default test set;
- ``<!-- runnable: slow -->``: the same, marked ``slow`` (``make test-slow``);
- ``<!-- runnable: help -->``, and every unmarked bash fence: each command is checked at
  ``--help`` level, without doing its work: ``fetchbench A B ...`` parses ``A B ... --help``
  (so the sub-commands and positional choices exist), a script runs with ``--help``, a make
  target with ``make -n``; plain shell commands (``cp``, ``export``, loops) are not run.

Plus: no page longer than its limit (generated blocks not counted), no words about how the
team works, and every script in scripts/ answers ``--help`` and is in scripts/README.md.
"""
from __future__ import annotations

import contextlib
import io
import os
import re
import shlex
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
README_LIMIT = 200
PAGE_LIMIT = 310  # "about 300 lines" of hand-written text a page
MARKER = re.compile(r"^<!--\s*runnable(?::\s*(slow|help))?\s*-->\s*$")
FENCE = re.compile(r"^```(\w*)\s*$")
COMMAND_STARTS = ("fetchbench ", "python", "make ", "bash ", "nice ", "PYTHONPATH=")
# Shell words that are not project commands: not run by the --help check.
SHELL_WORDS = {"for", "do", "done", "dpkg", "ldconfig", "export", "cd", "cp", "wait", "cat", "split",
               "sleep", "echo", "rm", "mkdir", "ls", "tar", "git", "pip", "sudo", "apt-get", "then",
               "fi", "if", "while", "torchrun"}
# Work-process words (docs/architecture.md, "Rules for contributors": docs speak of the project).
PROCESS_WORDS = re.compile(r"session|\$OUT|\bour (?:GPU )?machines?\b|\bGPU machine's\b|\bdev(?:elopment)? machine"
                           r"|\bdevice (?:budget|time|tool)|\bmachine (?:loan|hold)s?\b|\bholds? of the\b",
                           re.IGNORECASE)


@dataclass(frozen=True)
class Fence:
    page: str
    line: int
    lang: str
    mode: str  # "run", "slow" or "help"
    text: str

    @property
    def id(self) -> str:
        return f"{self.page}:{self.line}"


def _fences() -> list[Fence]:
    found = []
    for page in PAGES:
        lines = page.read_text().splitlines()
        i = 0
        while i < len(lines):
            m = FENCE.match(lines[i])
            if not m:
                i += 1
                continue
            start = i
            j = i + 1
            while j < len(lines) and not lines[j].startswith("```"):
                j += 1
            body = "\n".join(lines[start + 1:j])
            lang = m.group(1)
            marker = MARKER.match(lines[start - 1]) if start else None
            first = next((b.strip() for b in body.splitlines() if b.strip() and not b.strip().startswith("#")), "")
            is_shell = lang in ("bash", "sh") or (lang == "" and first.startswith(COMMAND_STARTS))
            if marker:
                mode = {"slow": "slow", "help": "help"}.get(marker.group(1), "run")
                if mode == "help" and not is_shell:
                    raise AssertionError(f"{page.name}:{start + 1}: 'runnable: help' marks a {lang or 'plain'} fence")
                found.append(Fence(str(page.relative_to(ROOT)), start + 1, "python" if lang == "python" else "bash",
                                   mode, body))
            elif is_shell:
                found.append(Fence(str(page.relative_to(ROOT)), start + 1, "bash", "help", body))
            i = j + 1
    return found


FENCES = _fences()


def _commands(text: str) -> list[list[str]]:
    """The simple commands of a bash fence: continuations joined, optional synopsis parts
    (`` [--flag]``) and comments dropped, split at && || ; | &, leading VAR=value words and
    wrappers (nice, timeout N, env) dropped."""
    joined = re.sub(r"\\\n", " ", text)
    joined = re.sub(r"(?<=\s)\[[^\]\n]*\]", " ", joined)   # synopsis: [--flag VALUE|--other]
    commands = []
    for line in joined.splitlines():
        lexer = shlex.shlex(line, posix=True, punctuation_chars=";&|")
        lexer.whitespace_split = True
        lexer.commenters = "#"
        tokens = list(lexer)
        current: list[str] = []
        for tok in tokens + [";"]:
            if tok in (";", "&&", "||", "|", "&", ";;"):
                while current and re.match(r"^[A-Za-z_][A-Za-z0-9_]*=", current[0]):
                    current.pop(0)
                while current and current[0] in ("nice", "env", "time"):
                    current.pop(0)
                if current and current[0] == "timeout":
                    current = current[2:]
                if current:
                    commands.append(current)
                current = []
            else:
                current.append(tok)
    return commands


def _run(args, timeout=300, **kw):
    env = dict(os.environ, PYTHONPATH=f"{ROOT}{os.pathsep}{os.environ.get('PYTHONPATH', '')}")
    return subprocess.run(args, cwd=ROOT, env=env, capture_output=True, text=True, timeout=timeout, **kw)


_SCRIPT_HELP: dict[str, str | None] = {}
# One interpreter answers every Python script's --help (runpy, as `python SCRIPT --help` /
# `python -m MODULE --help` would run it): their imports are paid once, not once a script.
_HELP_RUNNER = """
import contextlib, io, json, os, runpy, sys
results = {}
for key in json.loads(sys.argv[1]):
    kind, target = key.split(" ", 1)
    sys.argv = [target, "--help"]
    out = io.StringIO()
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
            if kind == "-m":
                runpy.run_module(target, run_name="__main__", alter_sys=True)
            else:  # as `python SCRIPT` does: the script's folder first on sys.path
                sys.path.insert(0, os.path.dirname(target))
                try:
                    runpy.run_path(target, run_name="__main__")
                finally:
                    sys.path.pop(0)
        code = 0
    except SystemExit as e:
        code = 0 if e.code is None else e.code if isinstance(e.code, int) else 1
    except BaseException as e:
        code, out = 1, io.StringIO(repr(e))
    results[key] = [code, out.getvalue()[-400:]]
print(json.dumps(results))
"""


def _python_help(keys: list[str]) -> None:
    """Fills _SCRIPT_HELP for keys ("-m MODULE" or "path SCRIPT") not answered yet."""
    import json

    todo = [k for k in dict.fromkeys(keys) if k not in _SCRIPT_HELP]
    if not todo:
        return
    done = _run([sys.executable, "-c", _HELP_RUNNER, json.dumps(todo)], timeout=600)
    assert done.returncode == 0, f"the --help runner failed: {done.stderr[-2000:]}"
    for key, (code, text) in json.loads(done.stdout.strip().splitlines()[-1]).items():
        _SCRIPT_HELP[key] = None if code == 0 else f"`python {key.split(' ', 1)[1]} --help` exited {code}: {text}"


def _python_keys(fences) -> list[str]:
    keys = []
    for fence in fences:
        for c in _commands(fence.text):
            if c[0] in ("python", "python3") and len(c) > 1:
                if c[1] == "-m" and c[2] != "fetchbench_ms":
                    keys.append(f"-m {c[2]}")
                elif c[1] != "-m" and (ROOT / c[1]).is_file():
                    keys.append(f"path {ROOT / c[1]}")
    return keys


def _script_help(argv: list[str]) -> str | None:
    """None when ``argv --help`` exits 0 (cached), else the reason."""
    if argv[0] == sys.executable:
        key = f"-m {argv[2]}" if argv[1] == "-m" else f"path {argv[1]}"
        _python_help([key])
        return _SCRIPT_HELP[key]
    key = " ".join(argv)
    if key not in _SCRIPT_HELP:
        done = _run([*argv, "--help"], timeout=180)
        _SCRIPT_HELP[key] = None if done.returncode == 0 else (
            f"`{key} --help` exited {done.returncode}: {(done.stderr or done.stdout).strip()[-400:]}")
    return _SCRIPT_HELP[key]


def _fetchbench_help(args: list[str]) -> str | None:
    from fetchbench_ms.cli import main

    path = []
    for a in args:
        if a.startswith("-"):
            break
        path.append(a)
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            main([*path, "--help"])
            code = 0
        except SystemExit as e:
            code = e.code or 0
    return None if code == 0 else f"`fetchbench {' '.join(path)} --help` exited {code}: {err.getvalue().strip()[-400:]}"


def _check_help(command: list[str]) -> str | None:
    word = command[0]
    if word == "fetchbench":
        return _fetchbench_help(command[1:])
    if word in ("python", "python3"):
        if command[1:3] == ["-m", "fetchbench_ms"]:
            return _fetchbench_help(command[3:])
        if command[1] == "-m":
            return _script_help([sys.executable, "-m", command[2]])
        script = ROOT / command[1]
        if not script.is_file():
            return f"no script {command[1]}"
        return _script_help([sys.executable, str(script)])
    if word == "bash":
        script = ROOT / command[1]
        if not script.is_file():
            return f"no script {command[1]}"
        return _script_help(["bash", str(script)])
    if word == "make":
        done = _run(["make", "-n", *command[1:]], timeout=60)
        return None if done.returncode == 0 else f"`make -n {' '.join(command[1:])}` exited {done.returncode}"
    if word in SHELL_WORDS or word.startswith(("./.", "$")):
        return None
    return f"unknown command `{word}` (a project command, or add it to SHELL_WORDS)"


def _ids(fences):
    return [f.id for f in fences]


HELP = [f for f in FENCES if f.mode == "help"]
RUN = [f for f in FENCES if f.mode == "run"]
SLOW = [f for f in FENCES if f.mode == "slow"]


_FETCHBENCH_RUNNER = """
import json, sys
from fetchbench_ms.cli import main
for args in json.loads(sys.argv[1]):
    code = main(args)
    if code:
        sys.exit(f"fetchbench {' '.join(args)}: exit status {code}")
"""


def _run_fence(fence: Fence, timeout: int):
    import json

    commands = _commands(fence.text)
    if fence.lang == "bash" and commands and all(c[0] == "fetchbench" for c in commands) \
            and not any(re.search(r"[|<>`$]", line.split(" #")[0]) for line in fence.text.splitlines()):
        # only fetchbench commands joined by newlines or &&: the same calls in one interpreter
        done = _run([sys.executable, "-c", _FETCHBENCH_RUNNER, json.dumps([c[1:] for c in commands])],
                    timeout=timeout)
    elif fence.lang == "python":
        done = _run([sys.executable, "-c", fence.text], timeout=timeout)
    else:
        prelude = (f'set -e\nPY="{sys.executable}"\nfetchbench() {{ "$PY" -m fetchbench_ms "$@"; }}\n'
                   'python() { "$PY" "$@"; }\npython3() { "$PY" "$@"; }\n')
        done = _run(["bash", "-c", prelude + fence.text], timeout=timeout)
    assert done.returncode == 0, (f"{fence.id} exited {done.returncode}:\n{fence.text}\n"
                                  f"{(done.stderr or done.stdout)[-2000:]}")


@pytest.fixture(scope="module")
def python_help_answers():
    """Every Python script the docs and scripts/ name, answered in one interpreter."""
    _python_help(_python_keys(HELP) + [f"path {p}" for p in SCRIPTS if p.suffix == ".py"])


@pytest.mark.parametrize("fence", HELP, ids=_ids(HELP))
def test_documented_commands_parse(fence, python_help_answers):
    problems = [p for c in _commands(fence.text) if (p := _check_help(c))]
    assert not problems, f"{fence.id}:\n" + "\n".join(problems)


@pytest.mark.parametrize("fence", RUN, ids=_ids(RUN))
def test_runnable_fences_run(fence):
    _run_fence(fence, timeout=300)


@pytest.mark.slow
@pytest.mark.parametrize("fence", SLOW, ids=_ids(SLOW))
def test_slow_runnable_fences_run(fence):
    _run_fence(fence, timeout=1200)


def test_the_docs_have_runnable_fences_of_every_kind():
    """The extraction finds what the pages mark (a marker typo would silently drop a fence)."""
    assert len(RUN) >= 8 and len(SLOW) >= 5 and len(HELP) >= 20
    for page in PAGES:
        for n, line in enumerate(page.read_text().splitlines(), 1):
            if "runnable" in line and line.startswith("<!--"):
                assert MARKER.match(line), f"{page.name}:{n}: malformed marker {line!r}"


def _hand_written_lines(text: str) -> int:
    """Lines outside generated blocks (``<!-- results-table:begin/end -->``); a page whose
    head says ``<!-- generated by`` is generated as a whole."""
    if "<!-- generated by" in "\n".join(text.splitlines()[:5]):
        return 0
    count, generated = 0, False
    for line in text.splitlines():
        if re.match(r"<!-- [\w-]+:begin -->", line):
            generated = True
        if not generated:
            count += 1
        if re.match(r"<!-- [\w-]+:end -->", line):
            generated = False
    return count


@pytest.mark.parametrize("page", PAGES, ids=[p.name for p in PAGES])
def test_pages_stay_within_their_line_limit(page):
    limit = README_LIMIT if page.name == "README.md" else PAGE_LIMIT
    lines = _hand_written_lines(page.read_text())
    assert lines <= limit, f"{page.relative_to(ROOT)}: {lines} lines, more than {limit}: split it or cut history"


def test_no_words_about_how_the_team_works():
    found = []
    for page in [*PAGES, ROOT / "scripts" / "README.md"]:
        for n, line in enumerate(page.read_text().splitlines(), 1):
            if PROCESS_WORDS.search(line):
                found.append(f"{page.relative_to(ROOT)}:{n}: {line.strip()[:120]}")
    assert not found, "docs speak of the project, not of how it was made:\n" + "\n".join(found)


def test_every_doc_link_resolves():
    missing = []
    for page in [*PAGES, ROOT / "scripts" / "README.md"]:
        for target in re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", page.read_text()):
            if "://" in target:
                continue
            if not (page.parent / target).exists():
                missing.append(f"{page.relative_to(ROOT)} -> {target}")
    assert not missing, "\n".join(missing)


SCRIPTS = sorted(p for p in (ROOT / "scripts").rglob("*") if p.suffix in (".py", ".sh") and p.name != "torch_cpu.sh")


def test_every_script_is_in_the_scripts_readme():
    table = (ROOT / "scripts" / "README.md").read_text()
    absent = [str(p.relative_to(ROOT / "scripts")) for p in SCRIPTS if f"`{p.relative_to(ROOT / 'scripts')}" not in table]
    assert not absent, f"scripts/README.md lacks: {absent}"


@pytest.mark.parametrize("script", SCRIPTS, ids=[str(p.relative_to(ROOT)) for p in SCRIPTS])
def test_every_script_answers_help(script, python_help_answers):
    argv = ["bash", str(script)] if script.suffix == ".sh" else [sys.executable, str(script)]
    assert _script_help(argv) is None, _script_help(argv)


def test_shipped_records_name_scripts_that_exist():
    """A shipped record's command (a checkpoint's retrain command, a round's command) stays a
    command that runs: every script path it names exists (moved scripts leave a forwarder)."""
    records = [*(ROOT / "assets" / "checkpoints").glob("*.json"), *(ROOT / "results" / "training").rglob("*.json")]
    named = {m for path in records for m in re.findall(r"\b(?:scripts|baselines)/[\w/.-]+\.(?:py|sh)\b", path.read_text())}
    assert named, "no record names a script: the pattern is stale"
    missing = sorted(n for n in named if not (ROOT / n).is_file())
    assert not missing, f"shipped records name scripts that no longer exist: {missing}"
