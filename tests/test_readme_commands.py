"""Every command block of README.md runs as written, in README order (issue #67).

What is run:

- The fenced ```bash and ```sh blocks of README.md, one test per block, in README order,
  and the ```python block under "## Python", run as a script. Lines ending in a
  backslash are joined with the next; comments (``#`` to the end of the line, outside
  quotes) and blank lines are dropped; each remaining line is one command.
- Setup is not run: ``make`` targets (``make demo``, ``make test``: they build the
  environment this test runs in, and ``make test`` runs this test), ``python -m venv``
  and ``pip install`` lines. A block left with no command is skipped, saying so.
- Every other command must be ``stickslip ...`` (a new kind of command fails here until
  this file knows how to run it). It runs without a shell, through the ``stickslip``
  executable beside ``sys.executable``, with ``MPLBACKEND=Agg``, in one temporary folder
  shared by the whole module that holds a symlink ``fixtures`` to the repository's
  fixtures: the README's relative paths resolve as from the repository root, outputs
  (``out/...``) land in the temporary folder, nothing is written into the repository.
  Blocks run in README order, so a later block reads what an earlier one wrote
  (``out/id/params.json``). A block run alone (``-k``), or on another xdist worker than
  the blocks before it, first runs the earlier commands that write what it reads: the
  ``xdist_group`` mark keeps the blocks on one worker under ``--dist loadgroup``, which
  pytest 9.2 silently breaks (pytest-dev/pytest-xdist#1386; pyproject.toml keeps pytest
  below 9.2).
- Skips and reductions are only those in ``SKIPS`` and ``REDUCTIONS`` below, each tied to
  a phrase the README must say next to the command or block it changes (in the block's
  comments or the paragraph right after it): the README says what its test leaves out.

What is checked, per command: the exit code (0 unless ``EXIT_CODES`` says otherwise);
every path named after ``--out`` or ``--plot`` exists and is not empty (a file with
bytes, a folder with a visible entry); in an ``--out`` folder, the files the README says
the command writes (``OUTPUTS``; each name must occur in README.md) exist and are not
empty. The Python block must exit 0. Without running anything: every ``out/`` path a
command reads is written by an earlier README command that the test runs.

Run time on two CPU cores (2026-12-04, other jobs sharing the machine at times): 2 min 5 s
to 2 min 48 s with a warm compilation cache, 3 min 10 s with a fresh one; the set_05
diagnosis is about half of it (54-91 s), the Python block 22-39 s, the identification
12-22 s. ``--durations`` prints each block's time, ``-s`` each command's.
"""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
README = REPO / "README.md"
STICKSLIP = Path(sys.executable).parent / "stickslip"
TIMEOUT_S = 900  # per command; the longest one run (the set_05 diagnosis) takes ~100 s

pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("readme_commands")]


@dataclass(frozen=True)
class Change:
    """A command (or the Python block) the README test leaves out or runs reduced.

    ``applies_to``: a prefix of the joined command (for the Python block: a substring of
    its source that must occur exactly once); ``old`` -> ``new``: the text replaced in it
    (``old=None``: not run at all); ``readme_says``: the phrase the README says next to
    it; ``why``: for the test's report.
    """

    applies_to: str
    old: str | None
    new: str
    readme_says: str
    why: str


SKIPS = (
    Change("stickslip diagnose fixtures/concealed/set_04", None, "",
           "the README test does not run it",
           "identification plus diagnosis: about 6 min on two cores"),
)

REDUCTIONS = (
    Change("stickslip design-experiment", "--fix Ms=0.0247",
           "--fix Ms=0.0247 --entries stribeck,external_load",
           "the README test asks it about two entries",
           "its ten questions take about 2 min on two busy cores; two run its every step"),
    Change("ss.diagnose(", "ss.diagnose(", '__import__("inspect").signature(ss.diagnose).bind(',
           "the README test runs it with",
           "the same diagnosis as `stickslip diagnose fixtures/concealed/set_05 ... "
           "--skip-identify` (run by the diagnosis block) takes about 2 min in a library "
           "process without the compilation cache; the call's arguments are checked "
           "against its signature instead"),
)

# Exit codes other than 0 that the README documents for a command (prefix -> code).
EXIT_CODES: dict[str, int] = {}

# Files the README says a command writes into its --out folder.
OUTPUTS = {
    "identify": ("params.json", "fit.json", "figures"),
    "sweep": ("velocity_map.csv", "velocity_map.png"),
    "zba-surface": ("zba_surface.json",),
    "contacts": ("contacts.json",),
    "diagnose": ("diagnosis.json", "report.md", "params.json", "baseline_params.json",
                 "figures"),
    "design-experiment": ("plan.json", "plan.md", "drives", "figures"),
}

PATH_OPTIONS = ("--out", "--plot")
SHELL_SYNTAX = re.compile(r"[|&;<>*?$`]")


@dataclass(frozen=True)
class Block:
    index: int
    line: int  # 1-based line of the opening fence
    lang: str
    section: str
    source: str  # the block's text, comments included
    context: str  # the block's text and the paragraph right after it

    @property
    def id(self) -> str:
        slug = re.sub(r"[^a-z0-9]+", "-", self.section.lower()).strip("-")
        return f"{self.index:02d}-{slug}-{self.lang}"


def _parse_blocks(text: str) -> list[Block]:
    lines = text.splitlines()
    blocks: list[Block] = []
    section = ""
    i = 0
    while i < len(lines):
        line = lines[i]
        if line.startswith("#") and not line.startswith("#!"):
            section = line.lstrip("#").strip()
        m = re.match(r"^```(\w+)\s*$", line)
        if m:
            lang, start = m.group(1), i
            j = i + 1
            while j < len(lines) and not lines[j].startswith("```"):
                j += 1
            body = "\n".join(lines[start + 1:j])
            k = j + 1  # the paragraph after the block: up to the next blank line after text
            while k < len(lines) and not lines[k].strip():
                k += 1
            while k < len(lines) and lines[k].strip() and not lines[k].startswith("```"):
                k += 1
            after = "\n".join(lines[j + 1:k])
            wanted = lang in ("bash", "sh") or (lang == "python" and section == "Python")
            if wanted:
                blocks.append(Block(len(blocks), start + 1, lang, section, body,
                                    body + "\n" + after))
            i = j + 1
            continue
        i += 1
    return blocks


def _commands(source: str) -> list[str]:
    """Joined continuation lines, comments and blank lines dropped; one string each."""
    joined: list[str] = []
    pending = ""
    for raw in source.splitlines():
        line = raw.rstrip()
        if line.endswith("\\") and not line.lstrip().startswith("#"):
            pending += line[:-1] + " "
            continue
        joined.append(pending + line)
        pending = ""
    if pending:
        joined.append(pending)
    out = []
    for line in joined:
        words = shlex.split(line, comments=True)
        if words:
            out.append(shlex.join(words))
    return out


def _is_setup(argv: list[str]) -> bool:
    if argv[0] == "make":
        return True
    text = " ".join(argv)
    return bool(re.search(r"(^|\s)-m venv(\s|$)", text) or re.search(r"pip install", text))


def _says(block: Block, phrase: str) -> bool:
    """Whether the block's comments or the paragraph after it say ``phrase``."""
    plain = re.sub(r"(?m)^\s*#\s?", "", block.context)
    return " ".join(phrase.split()) in " ".join(plain.split())


README_TEXT = README.read_text(encoding="utf-8")
BLOCKS = _parse_blocks(README_TEXT)


@dataclass(frozen=True)
class Step:
    """One command of a shell block: as written, and as the test runs it."""

    pos: int  # README order among all steps
    block: Block
    written: str
    run: str | None  # None: skipped (``change`` says why)
    change: Change | None

    @property
    def argv(self) -> list[str]:
        return shlex.split(self.run if self.run is not None else self.written)

    @property
    def outputs(self) -> list[str]:
        argv = self.argv
        return [argv[k + 1] for k, w in enumerate(argv[:-1]) if w in PATH_OPTIONS]

    @property
    def inputs(self) -> list[str]:
        """Paths it reads that an earlier command writes (under out/)."""
        outs = set(self.outputs)
        return [w for w in self.argv if w.startswith("out/") and w not in outs]


def _change_for(command: str, changes) -> Change | None:
    hits = [c for c in changes if c.old is None or c.old in command]
    hits = [c for c in hits if command.startswith(c.applies_to)]
    assert len(hits) <= 1, f"more than one change applies to {command!r}"
    return hits[0] if hits else None


def _steps() -> list[Step]:
    steps: list[Step] = []
    for block in BLOCKS:
        if block.lang == "python":
            continue
        for command in _commands(block.source):
            if _is_setup(shlex.split(command)):
                continue
            run: str | None = command
            change = _change_for(command, SKIPS)
            if change is not None:
                run = None
            else:
                change = _change_for(command, REDUCTIONS)
                if change is not None:
                    run = command.replace(change.old, change.new)
            steps.append(Step(len(steps), block, command, run, change))
    return steps


STEPS = _steps()


def _producer(path: str, step: Step) -> Step | None:
    """The last command before ``step`` in README order that writes ``path``."""
    for earlier in reversed(STEPS[:step.pos]):
        for out in earlier.outputs:
            if path == out or path.startswith(out.rstrip("/") + "/"):
                return earlier
    return None


@pytest.fixture(scope="module")
def workdir(tmp_path_factory) -> Path:
    """One folder for the whole README, as a fresh clone's root: fixtures/ linked in."""
    d = tmp_path_factory.mktemp("readme")
    (d / "fixtures").symlink_to(REPO / "fixtures", target_is_directory=True)
    return d


@pytest.fixture(scope="module")
def done() -> dict[int, bool]:
    """Step position -> whether it ran and passed, in this process's ``workdir``."""
    return {}


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["MPLBACKEND"] = "Agg"
    return env


def _nonempty(path: Path) -> bool:
    if path.is_dir():
        return any(not p.name.startswith(".") for p in path.iterdir())
    return path.is_file() and path.stat().st_size > 0


def _tail(text: str, n: int = 3000) -> str:
    return text if len(text) <= n else "..." + text[-n:]


def _run_command(command: str, cwd: Path) -> None:
    argv = shlex.split(command)
    bad = [w for w in argv if SHELL_SYNTAX.search(w)]
    assert not bad, (f"{command!r}: {bad} needs a shell; the README test runs commands "
                     "without one (write the paths out)")
    assert argv[0] == "stickslip", (
        f"{command!r}: the README test runs only `stickslip` commands and skips setup "
        "(make, venv, pip); teach tests/test_readme_commands.py this one")
    t0 = time.perf_counter()
    res = subprocess.run([str(STICKSLIP), *argv[1:]], cwd=cwd, env=_env(), text=True,
                         capture_output=True, timeout=TIMEOUT_S, check=False)
    print(f"[{time.perf_counter() - t0:6.1f} s] {command}")
    want = next((code for prefix, code in EXIT_CODES.items() if command.startswith(prefix)), 0)
    assert res.returncode == want, (
        f"{command!r} exited {res.returncode}, the README implies {want}\n"
        f"--- stdout\n{_tail(res.stdout)}\n--- stderr\n{_tail(res.stderr)}")
    sub = argv[1]
    for k, word in enumerate(argv[:-1]):
        if word not in PATH_OPTIONS:
            continue
        target = cwd / argv[k + 1]
        assert _nonempty(target), f"{command!r}: {argv[k + 1]} ({word}) missing or empty"
        if word == "--out" and target.is_dir():
            for name in OUTPUTS.get(sub, ()):
                assert _nonempty(target / name), (
                    f"{command!r}: {argv[k + 1]}/{name}, which the README says it "
                    "writes, is missing or empty")
    if sub == "drive":  # prints its choices, writes nothing without --out
        assert res.stdout.strip(), f"{command!r} printed nothing"


def _run_producer(path: str, step: Step) -> Step:
    """The earlier README command that writes ``path`` for ``step``; it must exist and
    be one the test runs."""
    producer = _producer(path, step)
    assert producer is not None, (
        f"{step.written!r} reads {path}, which no earlier README command writes")
    assert producer.run is not None, (
        f"{step.written!r} reads {path} from {producer.written!r}, which the README "
        "test does not run")
    return producer


def _execute(step: Step, workdir: Path, done: dict[int, bool], for_step: Step | None = None):
    """Run ``step`` after whatever earlier command writes its missing inputs (blocks run
    in README order in one process, where nothing is missing; a block run alone, or on
    another xdist worker, first runs the earlier commands it reads from)."""
    if step.pos in done:
        assert done[step.pos], f"{step.written!r}, which {for_step.written!r} needs, failed"
        return
    for path in step.inputs:
        if (workdir / path).exists():
            continue
        _execute(_run_producer(path, step), workdir, done, for_step=step)
    if for_step is not None:
        print(f"[ needed ] by {for_step.written}:")
    done[step.pos] = False
    _run_command(step.run, workdir)
    done[step.pos] = True


def test_readme_lists_what_it_checks():
    """The test's tables match the README: outputs named, skips and reductions said, and
    every out/ path a command reads is written by an earlier command that runs."""
    assert BLOCKS, "no command blocks found in README.md"
    for sub, names in OUTPUTS.items():
        for name in names:
            assert name in README_TEXT, f"README.md no longer names {name} ({sub})"
    for change in (*SKIPS, *REDUCTIONS):
        where = [b for b in BLOCKS if change.applies_to in (
            b.source if b.lang == "python" else "\n".join(_commands(b.source)))]
        assert where, f"no README block holds {change.applies_to!r} any more: drop the entry"
        assert any(_says(b, change.readme_says) for b in where), (
            f"README.md must say {change.readme_says!r} next to {change.applies_to!r} "
            f"({change.why})")
    for step in STEPS:
        for path in step.inputs:
            _run_producer(path, step)


@pytest.mark.parametrize("block", BLOCKS, ids=[b.id for b in BLOCKS])
def test_readme_block(block: Block, workdir: Path, done: dict[int, bool]):
    if block.lang == "python":
        _run_python(block, workdir)
        return
    steps = [s for s in STEPS if s.block == block]
    if not steps:
        pytest.skip("setup only (make targets, venv, pip): not run by the README test")
    for step in steps:
        if step.change is not None:
            assert _says(block, step.change.readme_says), (
                f"{step.written!r} is {'skipped' if step.run is None else 'reduced'} but "
                f"the README does not say {step.change.readme_says!r} next to it")
        if step.run is None:
            print(f"[ skipped] {step.written}: {step.change.why}")
            continue
        _execute(step, workdir, done)


def _run_python(block: Block, workdir: Path) -> None:
    source = block.source
    for change in REDUCTIONS:
        if change.applies_to not in source:
            continue
        assert source.count(change.old) == 1, f"{change.old!r} not once in the Python block"
        assert _says(block, change.readme_says), (
            f"the Python block runs reduced but the README does not say "
            f"{change.readme_says!r} next to it")
        source = source.replace(change.old, change.new)
    script = workdir / "readme_python_block.py"
    script.write_text(source, encoding="utf-8")
    t0 = time.perf_counter()
    res = subprocess.run([sys.executable, script.name], cwd=workdir, env=_env(), text=True,
                         capture_output=True, timeout=TIMEOUT_S, check=False)
    print(f"[{time.perf_counter() - t0:6.1f} s] README python block")
    assert res.returncode == 0, (
        f"the README's Python block (line {block.line}) exited {res.returncode}\n"
        f"--- stdout\n{_tail(res.stdout)}\n--- stderr\n{_tail(res.stderr)}")
