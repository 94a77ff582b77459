"""The user's documentation (docs/, mkdocs.yml, README.md): the site builds strictly, README's
links land on its pages, every command and exit code is documented, and the pages' `console`
examples run and print what they show."""

from __future__ import annotations

import html
import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from espdock.cli.reference import command as cli

ROOT = Path(__file__).resolve().parents[2]
DOCS = ROOT / "docs"
ESPDOCK = Path(sys.executable).with_name("espdock")

# A page says why an example cannot run here in the line just before it.
NOT_RUN = re.compile(r"^\*Not run by the docs' tests: (?P<reason>.+?)\.?\*$")
FENCE = re.compile(r"^```console\n(?P<body>.*?)^```$", re.MULTILINE | re.DOTALL)


def mkdocs_build(config: Path, site: Path) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}
    argv = [sys.executable, "-m", "mkdocs", "build", "--strict", "-f", str(config), "-d", str(site)]
    return subprocess.run(argv, capture_output=True, text=True, env=env, timeout=300, check=False)


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("site")
    result = mkdocs_build(ROOT / "mkdocs.yml", out)
    assert result.returncode == 0, result.stderr
    return out


def page_html(site: Path, page: str) -> str:
    name = page.removesuffix(".md")
    return (site / ("index.html" if name == "index" else f"{name}/index.html")).read_text()


def test_the_site_has_every_page_and_the_generated_command_reference(site: Path) -> None:
    for page in DOCS.glob("*.md"):
        assert page_html(site, page.name)
    reference = page_html(site, "reference.md")
    words = squeeze(html.unescape(re.sub(r"<[^>]+>", "", reference)))
    for name, sub in cli.commands.items():
        assert f'id="espdock-{name}"' in reference, name
        assert squeeze((sub.help or "").split("\n\n")[0].replace("`", "")) in words, name
        # Each of its options: the page had none (mkdocs-click's table takes click's own Option,
        # and Typer's options are its vendored click's).
        section = html.unescape(
            re.sub(r"<[^>]+>", "", reference.split(f'id="espdock-{name}"')[1].split('id="espdock-')[0])
        )
        listed = section.partition("Options:")[2]  # not the description's mentions
        for param in sub.params:
            if param.param_type_name == "option" and not param.hidden:
                assert all(opt in listed for opt in param.opts), (name, param.opts)


def test_a_broken_link_a_missing_anchor_and_a_page_out_of_the_nav_fail_the_build(tmp_path: Path) -> None:
    copy = tmp_path / "project"
    shutil.copytree(DOCS, copy / "docs")
    shutil.copy(ROOT / "mkdocs.yml", copy / "mkdocs.yml")
    with (copy / "docs" / "engines.md").open("a") as page:
        page.write("\n[gone](no-such-page.md) and [moved](ros.md#no-such-section)\n")
    (copy / "docs" / "orphan.md").write_text("# Orphan\n")
    result = mkdocs_build(copy / "mkdocs.yml", tmp_path / "site")
    assert result.returncode != 0
    # Each is a warning (which --strict turns into failure), not mkdocs' default info line.
    records = re.split(r"\n(?=[A-Z]+ +- )", result.stderr)
    for fault in ("no-such-page.md", "#no-such-section", "orphan.md"):
        levels = [record.split()[0] for record in records if fault in record]
        assert levels and set(levels) == {"WARNING"}, (fault, levels)


def test_readme_links_land_on_pages_and_sections(site: Path) -> None:
    readme = (ROOT / "README.md").read_text()
    links = re.findall(r"\]\(docs/([^)#]+\.md)(?:#([^)]+))?\)", readme)
    assert len({page for page, _ in links}) >= 10
    for page, anchor in links:
        assert (DOCS / page).is_file(), page
        if anchor:
            assert f'id="{anchor}"' in page_html(site, page), f"docs/{page}#{anchor}"


def test_readme_keeps_the_two_make_commands_and_fits_a_few_screens() -> None:
    readme = (ROOT / "README.md").read_text()
    assert re.search(r"^make demo +# set everything up", readme, re.MULTILINE)
    assert re.search(r"^make test +# set everything up", readme, re.MULTILINE)
    assert len(readme.splitlines()) <= 250


def test_every_command_has_a_section_in_the_pages() -> None:
    text = "\n".join(page.read_text() for page in DOCS.glob("*.md"))
    for name in cli.commands:
        assert re.search(rf"^### `espdock {name}\b", text, re.MULTILINE), name


def test_every_exit_code_is_explained() -> None:
    import espdock.firmware.flashing  # noqa: F401  (its serial port error)
    from espdock.errors import EspdockError

    codes, todo = set(), [EspdockError]
    while todo:
        cls = todo.pop()
        codes.add(cls.exit_code)
        todo.extend(cls.__subclasses__())
    page = (DOCS / "troubleshooting.md").read_text()
    paragraph = page[page.index("Exit codes: ") :].split("\n\n")[0]
    explained = {int(n) for n in re.findall(r"(?<![\w.-])(\d+) (?=[a-z`(])", paragraph)}
    assert codes <= explained, sorted(codes - explained)


def examples() -> list:
    params = []
    for page in sorted(DOCS.glob("*.md")):
        text = page.read_text()
        for n, match in enumerate(FENCE.finditer(text)):
            before = text[: match.start()].rstrip("\n").rsplit("\n", 1)[-1]
            skip = NOT_RUN.match(before)
            marks = [pytest.mark.skip(reason=f"{page.name}: {skip['reason']}")] if skip else []
            params.append(pytest.param(match["body"], id=f"{page.stem}-{n}", marks=marks))
    return params


def steps(body: str) -> list[tuple[list[str], int, list[str]]]:
    """The session's commands, each with the exit code a `# exit N` comment expects (else 0) and
    the lines it shows as output."""
    out: list[tuple[list[str], int, list[str]]] = []
    lines = iter(body.splitlines())
    for line in lines:
        if line.startswith("$ "):
            command = line
            while command.endswith("\\"):
                command = command[:-1] + next(lines)
            expected = re.search(r"#\s*exit (\d+)", command)
            for part in command[2:].split("&&"):
                out.append((shlex.split(part, comments=True), 0, []))
            out[-1] = (out[-1][0], int(expected[1]) if expected else 0, [])
        elif line.strip():
            assert out, f"output before any command: {line!r}"
            out[-1][2].append(line)
    return out


def squeeze(text: str) -> str:
    return " ".join(text.split())


@pytest.mark.parametrize("body", examples())
def test_console_examples_run(body: str, tmp_path: Path) -> None:
    cwd = tmp_path / "scratch"
    cwd.mkdir()
    # A home of the session's own: no colcon defaults or state of the developer's reach it.
    env = {**os.environ, "HOME": str(tmp_path), "ESPDOCK_STATE_DIR": str(tmp_path / "state")}
    for argv, code, shown in steps(body):
        if argv[0] == "cd":
            cwd = (cwd / argv[1]).resolve()
            continue
        assert argv[0] == "espdock", f"the docs' examples run espdock only: {argv}"
        result = subprocess.run(
            [str(ESPDOCK), *argv[1:]], cwd=cwd, env=env, capture_output=True, text=True, timeout=120, check=False
        )
        output = squeeze(result.stdout + result.stderr)
        assert result.returncode == code, f"{shlex.join(argv)}: exit {result.returncode}\n{output}"
        for line in shown:
            assert squeeze(line) in output, f"{shlex.join(argv)} did not print {line!r}:\n{output}"


def test_each_command_s_synopsis_on_its_page_lists_its_options() -> None:
    """The `espdock X ...` line under each command's heading drifted from --help: `new` without
    --transport, `build` without --workspace-mode, `prune` without --volume, ..."""
    checked = 0
    for page in sorted(DOCS.glob("*.md")):
        lines = page.read_text().splitlines()
        for at, line in enumerate(lines):
            if not re.match(r"^### `espdock [a-z-]+", line):
                continue
            synopsis = next(text for text in lines[at + 1 : at + 4] if text.startswith("`espdock"))
            for part in synopsis.split(" / "):
                words = part.strip("`").split()
                command = cli.commands[words[1]]
                if hasattr(command, "commands") and len(words) > 2:
                    command = command.commands[words[2].split("|")[0]]
                options = {
                    opt for param in command.params if param.param_type_name == "option" and not param.hidden
                    for opt in (*param.opts, *param.secondary_opts) if opt.startswith("--")
                }  # fmt: skip
                said = set(re.findall(r"--[a-z][a-z0-9-]*", part))
                assert options - {"--workspace", "--help"} <= said <= options, (page.name, part)
                checked += 1
    assert checked >= 20, checked
