"""contract double: a small reader of the CMake that ESP-IDF projects and components use.

It stands in for CMake in the espdock IDF contract double (ESP-IDF cannot be fetched here):
it runs set/list/option/if/foreach/message/include/file(GLOB)/get_filename_component and
records project() and idf_component_register(); every other command is ignored. Errors
look like CMake's (`CMake Error at FILE:LINE (message):`).
"""

from __future__ import annotations

import glob
import os
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

FALSE_CONSTANTS = {"", "0", "OFF", "NO", "FALSE", "N", "IGNORE", "NOTFOUND"}
TRUE_CONSTANTS = {"1", "ON", "YES", "TRUE", "Y"}
UNARY = {"DEFINED", "EXISTS", "IS_DIRECTORY", "IS_ABSOLUTE", "COMMAND", "TARGET", "POLICY", "TEST"}
BINARY = {
    "STREQUAL",
    "STRLESS",
    "STRGREATER",
    "EQUAL",
    "LESS",
    "GREATER",
    "LESS_EQUAL",
    "GREATER_EQUAL",
    "MATCHES",
    "VERSION_LESS",
    "VERSION_GREATER",
    "VERSION_EQUAL",
    "VERSION_LESS_EQUAL",
    "VERSION_GREATER_EQUAL",
    "IN_LIST",
}


class CMakeError(Exception):
    """A configure error, already formatted as CMake prints it."""


@dataclass(frozen=True)
class Arg:
    text: str
    quoted: bool


@dataclass(frozen=True)
class Command:
    name: str
    args: tuple[Arg, ...]
    line: int


@dataclass
class Registration:
    """What one idf_component_register() call said."""

    srcs: list[str] = field(default_factory=list)
    src_dirs: list[str] = field(default_factory=list)
    exclude_srcs: list[str] = field(default_factory=list)
    include_dirs: list[str] = field(default_factory=list)
    priv_include_dirs: list[str] = field(default_factory=list)
    requires: list[str] = field(default_factory=list)
    priv_requires: list[str] = field(default_factory=list)
    line: int = 0


def parse(path: Path) -> list[Command]:
    """The command invocations of the CMake file PATH."""
    text = path.read_text(encoding="utf-8", errors="replace")
    commands: list[Command] = []
    i, line, n = 0, 1, len(text)
    while i < n:
        ch = text[i]
        if ch == "\n":
            line += 1
            i += 1
        elif ch.isspace():
            i += 1
        elif ch == "#":
            bracket = re.match(r"#\[(=*)\[", text[i:])
            if bracket:
                end = text.find("]" + bracket.group(1) + "]", i)
                end = n if end < 0 else end + len(bracket.group(1)) + 2
                line += text.count("\n", i, end)
                i = end
            else:
                while i < n and text[i] != "\n":
                    i += 1
        else:
            match = re.match(r"[A-Za-z_][A-Za-z0-9_]*", text[i:])
            if not match:
                raise CMakeError(f"CMake Error at {path}:{line}:\n  Parse error: unexpected '{ch}'")
            name = match.group(0)
            start_line = line
            i += len(name)
            while i < n and text[i] in " \t":
                i += 1
            if i >= n or text[i] != "(":
                raise CMakeError(f"CMake Error at {path}:{start_line}:\n  Parse error.  Expected '(' after {name}")
            i += 1
            args, i, line = _parse_args(text, i, line, path, start_line)
            commands.append(Command(name.lower(), tuple(args), start_line))
    return commands


def _parse_args(text: str, i: int, line: int, path: Path, start_line: int) -> tuple[list[Arg], int, int]:
    args: list[Arg] = []
    depth = 0
    n = len(text)
    while i < n:
        ch = text[i]
        if ch == "\n":
            line += 1
            i += 1
        elif ch.isspace():
            i += 1
        elif ch == "#":
            while i < n and text[i] != "\n":
                i += 1
        elif ch == ")":
            if depth == 0:
                return args, i + 1, line
            depth -= 1
            args.append(Arg(")", False))
            i += 1
        elif ch == "(":
            depth += 1
            args.append(Arg("(", False))
            i += 1
        elif ch == '"':
            j = i + 1
            buf = []
            while j < n and text[j] != '"':
                if text[j] == "\\" and j + 1 < n:
                    nxt = text[j + 1]
                    if nxt == "\n":
                        line += 1
                    else:
                        buf.append({"n": "\n", "t": "\t", "r": "\r", ";": "\\;"}.get(nxt, nxt))
                    j += 2
                    continue
                if text[j] == "\n":
                    line += 1
                buf.append(text[j])
                j += 1
            args.append(Arg("".join(buf), True))
            i = j + 1
        elif ch == "[" and re.match(r"\[(=*)\[", text[i:]):
            eq = re.match(r"\[(=*)\[", text[i:]).group(1)
            end = text.find("]" + eq + "]", i)
            end = n if end < 0 else end
            body = text[i + len(eq) + 2 : end]
            line += body.count("\n")
            args.append(Arg(body.lstrip("\n"), True))
            i = end + len(eq) + 2
        else:
            j = i
            buf = []
            while j < n and not text[j].isspace() and text[j] not in '()#"':
                if text[j] == "\\" and j + 1 < n:
                    buf.append(text[j : j + 2])
                    j += 2
                    continue
                buf.append(text[j])
                j += 1
            args.append(Arg("".join(buf), False))
            i = j
    raise CMakeError(f'CMake Error at {path}:{start_line}:\n  Parse error.  Function missing ending ")".')


class Interpreter:
    """Runs one CMake file with a variable scope; records project() and idf_component_register()."""

    def __init__(self, variables: Mapping[str, str], env: Mapping[str, str], warn: Callable[[str], None]) -> None:
        self.vars: dict[str, str] = dict(variables)
        self.env: dict[str, str] = dict(env)
        self.warn = warn
        self.project_name: str | None = None
        self.project_line = 0
        self.extra_component_dirs_at_project: list[str] = []
        # project.cmake reads SDKCONFIG_DEFAULTS as a variable too: a `set()` before project() wins.
        self.sdkconfig_defaults_at_project: str | None = None
        self.registrations: list[Registration] = []
        self.included: list[str] = []
        self.file = Path()

    # variable expansion

    def expand(self, text: str) -> str:
        pattern = re.compile(r"\$(ENV|CACHE)?\{([^${}]*)\}")
        for _ in range(32):
            new = pattern.sub(self._lookup, text)
            if new == text:
                break
            text = new
        return text

    def _lookup(self, match: re.Match[str]) -> str:
        kind, name = match.group(1), match.group(2)
        if kind == "ENV":
            return self.env.get(name, "")
        return self.vars.get(name, "")

    def values(self, args: tuple[Arg, ...]) -> list[str]:
        """ARGS expanded as CMake passes them: unquoted ones split on ';' and empty ones dropped."""
        out: list[str] = []
        for arg in args:
            value = self.expand(arg.text)
            if arg.quoted:
                out.append(value.replace("\\;", ";"))
            else:
                out.extend(part for part in re.split(r"(?<!\\);", value) if part != "")
        return [v.replace("\\;", ";") for v in out]

    # running

    def run_file(self, path: Path) -> None:
        self.file = path
        commands = parse(path)
        self._run_block(commands, 0, len(commands))

    def _run_block(self, commands: list[Command], start: int, end: int) -> bool:
        """Run COMMANDS[start:end]; False when return() was hit."""
        pc = start
        while pc < end:
            cmd = commands[pc]
            if cmd.name == "if":
                pc, keep_going = self._run_if(commands, pc, end)
                if not keep_going:
                    return False
                continue
            if cmd.name in ("foreach", "while", "function", "macro"):
                close = self._matching(commands, pc, end, cmd.name, "end" + cmd.name)
                if cmd.name == "foreach" and not self._run_foreach(commands, cmd, pc + 1, close):
                    return False
                pc = close + 1
                continue
            if cmd.name == "return":
                return False
            self._command(cmd)
            pc += 1
        return True

    def _matching(self, commands: list[Command], pc: int, end: int, opener: str, closer: str) -> int:
        depth = 0
        for j in range(pc, end):
            if commands[j].name == opener:
                depth += 1
            elif commands[j].name == closer:
                depth -= 1
                if depth == 0:
                    return j
        raise CMakeError(
            f"CMake Error at {self.file}:{commands[pc].line} ({opener}):\n  A logical block opening on the line\n"
            f"  is not closed."
        )

    def _run_if(self, commands: list[Command], pc: int, end: int) -> tuple[int, bool]:
        close = self._matching(commands, pc, end, "if", "endif")
        branches: list[tuple[int, Command]] = [(pc, commands[pc])]
        depth = 0
        for j in range(pc + 1, close):
            name = commands[j].name
            if name == "if":
                depth += 1
            elif name == "endif":
                depth -= 1
            elif depth == 0 and name in ("elseif", "else"):
                branches.append((j, commands[j]))
        bounds = [b[0] for b in branches] + [close]
        for k, (at, cmd) in enumerate(branches):
            taken = cmd.name == "else" or self.condition(cmd)
            if taken:
                return close + 1, self._run_block(commands, at + 1, bounds[k + 1])
        return close + 1, True

    def _run_foreach(self, commands: list[Command], cmd: Command, start: int, end: int) -> bool:
        values = self.values(cmd.args)
        if not values:
            return True
        var, items = values[0], values[1:]
        if items[:1] == ["IN"]:
            expanded: list[str] = []
            mode = None
            for item in items[1:]:
                if item in ("LISTS", "ITEMS"):
                    mode = item
                elif mode == "LISTS":
                    expanded += [x for x in self.vars.get(item, "").split(";") if x]
                else:
                    expanded.append(item)
            items = expanded
        elif items[:1] == ["RANGE"]:
            nums = [int(x) for x in items[1:]]
            items = [str(x) for x in (range(nums[0] + 1) if len(nums) == 1 else range(nums[0], nums[1] + 1))]
        for item in items:
            self.vars[var] = item
            if not self._run_block(commands, start, end):
                return False
        return True

    # conditions

    def condition(self, cmd: Command) -> bool:
        tokens: list[tuple[str, bool]] = []
        for arg in cmd.args:
            expanded = self.expand(arg.text)
            if arg.quoted:
                tokens.append((expanded, True))
            else:
                tokens.extend((part, False) for part in expanded.split(";") if part != "")
        try:
            value, rest = self._or(tokens)
        except (IndexError, ValueError) as exc:
            raise CMakeError(
                f"CMake Error at {self.file}:{cmd.line} ({cmd.name}):\n"
                f"  {cmd.name} given arguments it cannot evaluate: {exc}"
            ) from None
        if rest:
            raise CMakeError(f"CMake Error at {self.file}:{cmd.line} ({cmd.name}):\n  Unknown arguments specified")
        return value

    def _or(self, toks):
        value, toks = self._and(toks)
        while toks and toks[0] == ("OR", False):
            rhs, toks = self._and(toks[1:])
            value = value or rhs
        return value, toks

    def _and(self, toks):
        value, toks = self._not(toks)
        while toks and toks[0] == ("AND", False):
            rhs, toks = self._not(toks[1:])
            value = value and rhs
        return value, toks

    def _not(self, toks):
        if toks and toks[0] == ("NOT", False):
            value, rest = self._not(toks[1:])
            return not value, rest
        return self._test(toks)

    def _test(self, toks):
        if not toks:
            raise ValueError("missing operand")
        head = toks[0]
        if head == ("(", False):
            value, rest = self._or(toks[1:])
            if not rest or rest[0] != (")", False):
                raise ValueError("missing ')'")
            return value, rest[1:]
        if not head[1] and head[0] in UNARY:
            return self._unary(head[0], toks[1][0]), toks[2:]
        if len(toks) >= 3 and not toks[1][1] and toks[1][0] in BINARY:
            return self._binary(head, toks[1][0], toks[2]), toks[3:]
        return self._truth(head), toks[1:]

    def _unary(self, op: str, operand: str) -> bool:
        if op == "DEFINED":
            env = re.fullmatch(r"ENV\{(.*)\}", operand)
            if env:
                return env.group(1) in self.env
            cache = re.fullmatch(r"CACHE\{(.*)\}", operand)
            return (cache.group(1) if cache else operand) in self.vars
        if op == "EXISTS":
            return bool(operand) and os.path.exists(operand)
        if op == "IS_DIRECTORY":
            return bool(operand) and os.path.isdir(operand)
        if op == "IS_ABSOLUTE":
            return os.path.isabs(operand)
        return False

    def _deref(self, token: tuple[str, bool]) -> str:
        text, quoted = token
        if not quoted and text in self.vars:
            return self.vars[text]
        return text

    def _binary(self, lhs, op: str, rhs) -> bool:
        a, b = self._deref(lhs), self._deref(rhs)
        if op == "STREQUAL":
            return a == b
        if op == "STRLESS":
            return a < b
        if op == "STRGREATER":
            return a > b
        if op == "MATCHES":
            return re.search(rhs[0], a) is not None
        if op == "IN_LIST":
            return a in self.vars.get(rhs[0], "").split(";")
        if op.startswith("VERSION_"):
            va, vb = (tuple(int(x) for x in re.findall(r"\d+", v)) for v in (a, b))
            return {
                "VERSION_LESS": va < vb,
                "VERSION_GREATER": va > vb,
                "VERSION_EQUAL": va == vb,
                "VERSION_LESS_EQUAL": va <= vb,
                "VERSION_GREATER_EQUAL": va >= vb,
            }[op]
        try:
            x, y = float(a), float(b)
        except ValueError:
            return False
        return {"EQUAL": x == y, "LESS": x < y, "GREATER": x > y, "LESS_EQUAL": x <= y, "GREATER_EQUAL": x >= y}[op]

    def _truth(self, token: tuple[str, bool]) -> bool:
        text, quoted = token
        upper = text.upper()
        if upper in TRUE_CONSTANTS:
            return True
        if upper in FALSE_CONSTANTS or upper.endswith("-NOTFOUND"):
            return False
        if re.fullmatch(r"-?[0-9]+(\.[0-9]*)?", text):
            return float(text) != 0
        if quoted:
            return False
        if text not in self.vars:
            return False
        value = self.vars[text].upper()
        return not (value in FALSE_CONSTANTS or value.endswith("-NOTFOUND"))

    # commands

    def _command(self, cmd: Command) -> None:
        handler = getattr(self, "_cmd_" + cmd.name, None)
        if handler is not None:
            handler(cmd, self.values(cmd.args))

    def _cmd_set(self, cmd: Command, v: list[str]) -> None:
        if not v:
            return
        name, values = v[0], v[1:]
        if "PARENT_SCOPE" in values:
            values = values[: values.index("PARENT_SCOPE")]
        cache = "CACHE" in values
        if cache:
            values = values[: values.index("CACHE")]
        env = re.fullmatch(r"ENV\{(.*)\}", name)
        if env:
            self.env[env.group(1)] = values[0] if values else ""
            return
        if cache and name in self.vars and "FORCE" not in v:
            return
        if values:
            self.vars[name] = ";".join(values)
        else:
            self.vars.pop(name, None)

    def _cmd_unset(self, cmd: Command, v: list[str]) -> None:
        if v:
            env = re.fullmatch(r"ENV\{(.*)\}", v[0])
            if env:
                self.env.pop(env.group(1), None)
            else:
                self.vars.pop(v[0], None)

    def _cmd_option(self, cmd: Command, v: list[str]) -> None:
        if v and v[0] not in self.vars:
            self.vars[v[0]] = v[2] if len(v) > 2 else "OFF"

    def _cmd_list(self, cmd: Command, v: list[str]) -> None:
        if len(v) < 2:
            return
        op, name, items = v[0], v[1], v[2:]
        current = [x for x in self.vars.get(name, "").split(";") if x]
        if op == "APPEND":
            current += items
        elif op == "PREPEND":
            current = items + current
        elif op == "REMOVE_ITEM":
            current = [x for x in current if x not in items]
        elif op == "REMOVE_DUPLICATES":
            current = list(dict.fromkeys(current))
        else:
            return
        self.vars[name] = ";".join(current)

    def _cmd_message(self, cmd: Command, v: list[str]) -> None:
        modes = {
            "FATAL_ERROR",
            "SEND_ERROR",
            "WARNING",
            "AUTHOR_WARNING",
            "DEPRECATION",
            "NOTICE",
            "STATUS",
            "VERBOSE",
            "DEBUG",
            "TRACE",
            "CHECK_START",
            "CHECK_PASS",
            "CHECK_FAIL",
        }
        mode = v[0] if v and v[0] in modes else "NOTICE"
        text = "".join(v[1:] if v and v[0] in modes else v)
        if mode in ("FATAL_ERROR", "SEND_ERROR"):
            raise CMakeError(f"CMake Error at {self.file}:{cmd.line} (message):\n  " + text.replace("\n", "\n  "))
        if mode in ("WARNING", "AUTHOR_WARNING", "DEPRECATION"):
            self.warn(f"CMake Warning at {self.file}:{cmd.line} (message):\n  {text}\n")
        elif mode in ("STATUS", "NOTICE", "CHECK_START", "CHECK_PASS", "CHECK_FAIL"):
            self.warn(("-- " if mode == "STATUS" else "") + text)

    def _cmd_include(self, cmd: Command, v: list[str]) -> None:
        if not v:
            return
        target = v[0]
        optional = "OPTIONAL" in v[1:]
        if "/" not in target and not target.endswith(".cmake"):
            return  # a CMake module such as CMakePrintHelpers
        path = Path(target)
        if not path.is_absolute():
            path = Path(self.vars.get("CMAKE_CURRENT_SOURCE_DIR", ".")) / path
        if not path.is_file():
            if optional:
                return
            raise CMakeError(
                f"CMake Error at {self.file}:{cmd.line} (include):\n"
                f"  include could not find requested file:\n\n    {target}"
            )
        self.included.append(str(path))
        on_include = self.vars.get("__DOUBLE_IDF_PROJECT_CMAKE")
        if on_include and os.path.realpath(path) == os.path.realpath(on_include):
            self.vars["__DOUBLE_IDF_INCLUDED"] = "1"
            return  # the double's project.cmake is a marker, not something to run

    def _cmd_project(self, cmd: Command, v: list[str]) -> None:
        if not v:
            raise CMakeError(
                f"CMake Error at {self.file}:{cmd.line} (project):\n  project called with incorrect number of arguments"
            )
        self.project_name = v[0]
        self.project_line = cmd.line
        self.vars["PROJECT_NAME"] = v[0]
        self.vars["CMAKE_PROJECT_NAME"] = v[0]
        self.extra_component_dirs_at_project = [x for x in self.vars.get("EXTRA_COMPONENT_DIRS", "").split(";") if x]
        self.sdkconfig_defaults_at_project = self.vars.get("SDKCONFIG_DEFAULTS") or None

    def _cmd_get_filename_component(self, cmd: Command, v: list[str]) -> None:
        if len(v) < 3:
            return
        var, path, mode = v[0], v[1], v[2]
        base = self.vars.get("CMAKE_CURRENT_SOURCE_DIR", ".")
        if "BASE_DIR" in v[3:]:
            base = v[v.index("BASE_DIR") + 1]
        p = path.rstrip("/") if path not in ("/", "") else path
        result = {
            "NAME": os.path.basename(p),
            "DIRECTORY": os.path.dirname(p),
            "PATH": os.path.dirname(p),
            "ABSOLUTE": os.path.normpath(os.path.join(base, p)),
            "REALPATH": os.path.realpath(os.path.join(base, p)),
            "NAME_WE": os.path.basename(p).split(".")[0],
            "EXT": "." + ".".join(os.path.basename(p).split(".")[1:]) if "." in os.path.basename(p) else "",
        }.get(mode, "")
        self.vars[var] = result

    def _cmd_file(self, cmd: Command, v: list[str]) -> None:
        if not v or v[0] not in ("GLOB", "GLOB_RECURSE"):
            return
        recurse = v[0] == "GLOB_RECURSE"
        var = v[1]
        rest = v[2:]
        list_dirs = not recurse
        relative = None
        patterns = []
        i = 0
        while i < len(rest):
            word = rest[i]
            if word == "LIST_DIRECTORIES":
                list_dirs = rest[i + 1].upper() in TRUE_CONSTANTS
                i += 2
                continue
            if word == "RELATIVE":
                relative = rest[i + 1]
                i += 2
                continue
            if word in ("CONFIGURE_DEPENDS", "FOLLOW_SYMLINKS"):
                i += 1
                continue
            patterns.append(word)
            i += 1
        base = self.vars.get("CMAKE_CURRENT_SOURCE_DIR", ".")
        found: list[str] = []
        for pattern in patterns:
            full = pattern if os.path.isabs(pattern) else os.path.join(base, pattern)
            if recurse:
                head, tail = os.path.split(full)
                matches = glob.glob(os.path.join(head, "**", tail), recursive=True)
            else:
                matches = glob.glob(full)
            for m in matches:
                if not list_dirs and os.path.isdir(m):
                    continue
                found.append(os.path.relpath(m, relative) if relative else m)
        self.vars[var] = ";".join(sorted(set(found)))

    def _cmd_string(self, cmd: Command, v: list[str]) -> None:
        if len(v) < 3:
            return
        op = v[0]
        if op == "REGEX" and len(v) >= 4:
            sub = v[1]
            try:
                if sub == "REPLACE" and len(v) >= 5:
                    replacement = re.sub(r"\\(\d)", r"\\g<\1>", v[3])
                    self.vars[v[4]] = re.sub(v[2], replacement, "".join(v[5:]))
                elif sub == "MATCH":
                    m = re.search(v[2], "".join(v[4:]))
                    self.vars[v[3]] = m.group(0) if m else ""
                elif sub == "MATCHALL":
                    self.vars[v[3]] = ";".join(m.group(0) for m in re.finditer(v[2], "".join(v[4:])))
            except re.error as exc:
                raise CMakeError(
                    f"CMake Error at {self.file}:{cmd.line} (string):\n  string sub-command REGEX, "
                    f'mode {sub} failed to compile regex "{v[2]}": {exc}'
                ) from None
        elif op == "STRIP":
            self.vars[v[2]] = v[1].strip()
        elif op == "LENGTH":
            self.vars[v[2]] = str(len(v[1]))
        elif op in ("TOUPPER", "TOLOWER"):
            self.vars[v[2]] = v[1].upper() if op == "TOUPPER" else v[1].lower()
        elif op == "REPLACE" and len(v) >= 4:
            self.vars[v[3]] = "".join(v[4:]).replace(v[1], v[2])
        elif op == "APPEND":
            self.vars[v[1]] = self.vars.get(v[1], "") + "".join(v[2:])
        elif op == "CONCAT":
            self.vars[v[1]] = "".join(v[2:])

    def _cmd_idf_build_get_property(self, cmd: Command, v: list[str]) -> None:
        if len(v) >= 2:
            self.vars[v[0]] = {
                "IDF_TARGET": self.vars.get("IDF_TARGET", ""),
                "IDF_PATH": self.vars.get("IDF_PATH", ""),
                "BUILD_DIR": self.vars.get("BUILD_DIR", ""),
                "PROJECT_DIR": self.vars.get("PROJECT_DIR", ""),
                "PROJECT_NAME": self.vars.get("PROJECT_NAME", ""),
            }.get(v[1], "")

    def _cmd_idf_component_register(self, cmd: Command, v: list[str]) -> None:
        keys = {
            "SRCS": "srcs",
            "SRC_DIRS": "src_dirs",
            "EXCLUDE_SRCS": "exclude_srcs",
            "INCLUDE_DIRS": "include_dirs",
            "PRIV_INCLUDE_DIRS": "priv_include_dirs",
            "REQUIRES": "requires",
            "PRIV_REQUIRES": "priv_requires",
        }
        others = {
            "LDFRAGMENTS",
            "EMBED_FILES",
            "EMBED_TXTFILES",
            "KCONFIG",
            "KCONFIG_PROJBUILD",
            "WHOLE_ARCHIVE",
        }
        reg = Registration(line=cmd.line)
        current = None
        targets: list[str] = []
        for word in v:
            if word in keys:
                current = keys[word]
            elif word == "REQUIRED_IDF_TARGETS":
                current = "required_idf_targets"
            elif word in others:
                current = None
            elif current == "required_idf_targets":
                targets.append(word)
            elif current:
                getattr(reg, current).append(word)
        # ESP-IDF's tools/cmake/component.cmake, __component_check_target: a component that names its
        # targets stops the configure for any other, before anything compiles.
        target = self.vars.get("IDF_TARGET", "")
        if targets and target and target not in targets:
            raise CMakeError(
                f"CMake Error at {self.vars.get('IDF_PATH', '')}/tools/cmake/component.cmake:331 (message):\n"
                f"  Component {Path(self.file).parent.name} only supports targets: {';'.join(targets)}"
            )
        self.registrations.append(reg)
