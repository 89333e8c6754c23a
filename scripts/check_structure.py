#!/usr/bin/env python3
"""Structural checks of the GesTHOR-RS workspace (Python 3.11, standard library only).

    python3 scripts/check_structure.py [--root DIR]      # every check; exit 1 on a violation
    python3 scripts/check_structure.py --graph CRATE     # the crate's file dependency edges
    python3 scripts/check_structure.py --sizes           # non-test line counts, files over 400 lines
    python3 scripts/check_structure.py --fns [N]         # functions over N lines of code (default 60)
    python3 scripts/check_structure.py --self-test       # the script's own tests, on mini-crates

Rule 1: no import cycle between the source files of a crate.
    File A depends on file B when A names an item (fn, struct, enum, union, trait, type, const,
    static, macro_rules, or a module) defined in B: through `use crate::..`, `use super::..`,
    `use self::..`, a path relative to a module in scope (`model::ModelError` beside
    `mod model;`, `checkpoint::load` after `use crate::checkpoint;`), brace groups (nested,
    `self`, `as`), globs (A depends on the files defining the glob's names that A's code
    mentions; on the module's own file when it mentions none), or an inline path in code
    (`crate::a::b::f(..)`, `super::X`). Bins, integration tests, benches and examples that name
    the package's library (`use learner::model::X`) depend on the library's files too.
    Paths are resolved the Rust way from each target root (src/lib.rs, src/main.rs,
    src/bin/*.rs, [lib]/[[bin]]/[[test]]/[[bench]] paths from Cargo.toml, tests/, benches/,
    examples/, build.rs): `mod x;` is x.rs or x/mod.rs (nested, #[path] honoured), and an
    inline `mod x { .. }` belongs to the file that holds it.
    A `pub use` (any `pub(..)` too) is a facade, not a dependency: a path naming an item that a
    module only re-exports is followed to the file that defines the item. The re-exporting file
    depends on the item only if its own code mentions the name. Importing a module gives no
    edge by itself: the paths through it do (`checkpoint::load` -> the file defining `load`).
    Paths that do not resolve inside the crate (other crates, std, macro-generated items,
    generic parameters, `Self::`) are skipped silently. Self-edges are ignored.
    Every strongly connected component of more than one file is reported, with one example of
    what causes each edge inside it.

Rule 2: no source file over 700 non-test lines (500 under a folder of MAX_LINES_UNDER, such as
    orchestrator/src/), except the data tables in SIZE_ALLOWLIST.
    Non-test lines = lines of the file, minus lines of `#[cfg(test)]` items, minus blank lines
    and comment-only lines. Every .rs file under a member's directory is counted (integration
    tests and benches included); a file that is itself a `#[cfg(test)] mod x;` counts 0.

Rule 3: under a folder of MAX_FILES_UNDER (orchestrator/src, learner/src), no folder holds more than 12 .rs
    files of its own (mod.rs included; files in its subfolders count for those): a role whose
    files outgrow that becomes a folder of its own.

Rule 4: every relative link of the Markdown files (the root's *.md and every *.md below it, build
    and data folders skipped) names a file or folder that exists, and a `#anchor` into a Markdown
    file names one of its headings (GitHub's slugs). Links inside code (fenced blocks, `spans`)
    and to other sites (http:, mailto:) are not checked.

Rule 5: no function of a package's src/ folder over MAX_FN_LINES lines of code (lines holding
    a token between its body's braces, the braces included: blank and comment-only lines do not
    count), except those in FN_ALLOWLIST, each with its reason. Integration tests, benches and
    examples are not held to it.

Test code is ignored by rules 1, 2 and 5: every item under `#[cfg(test)]` (or `#[cfg(all(test, ..))]`):
`#[cfg(test)] mod tests { .. }`, the files of `#[cfg(test)] mod tests;` (and their submodules),
a `#[cfg(test)]` fn, impl, const or use, also one inside a fn body. Test code may look
anywhere. (`#[test]` functions outside such a module are not test code for this script.)

Comments, string literals (raw strings r#".."#, byte and C strings too) and char literals are
stripped before parsing; lifetimes and labels ('a) are told apart from char literals.

Known limits: paths hidden in strings (`#[serde(with = "crate::x")]`) or built by macros are
not seen (items a `macro_rules!` declares under a literal name, `pub enum Bone { $(..) }`, are
known); names from a glob, and the names a `pub use` file mentions, are matched by token, so
a local variable named like a glob-imported item may add an edge; a `use` inside a fn body is
treated as if it were at its module's level; `#[cfg(..)]` other than test is ignored (both
sides of a cfg are parsed); items defined inside fn bodies may be mistaken for module items
they shadow; `macro_rules!` bodies are scanned like code (`$crate::x` counts as `crate::x`).
"""

from __future__ import annotations

import argparse
import glob as globmod
import os
import re
import sys
import tempfile
import tomllib
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path

MAX_LINES = 700
SIZES_OVER = 400

# Stricter size limits: a folder (relative to the workspace root) -> most non-test lines of each
# .rs file under it. The longest matching folder wins.
MAX_LINES_UNDER: dict[str, int] = {
    'orchestrator/src': 500,
}

# Folders whose every folder (itself and each below it) holds at most this many .rs files.
MAX_FILES_UNDER: dict[str, int] = {
    'orchestrator/src': 12,
    'learner/src': 12,
}

# Files allowed over MAX_LINES: data tables only. Path relative to the workspace root -> a
# one-line reason, e.g.  "worker/src/scene/catalog.rs": "object catalogue: one row per category",
SIZE_ALLOWLIST: dict[str, str] = {
}

# Rule 5: the most lines of code of one function body under a package's src/ ("a screen").
MAX_FN_LINES = 80

# Functions allowed over MAX_FN_LINES: 'path::Owner::name' (path relative to the workspace root)
# -> why it reads best as one piece.
FN_ALLOWLIST: dict[str, str] = {
    'learner/src/net/pth.rs::unpickle': "the pickle machine: one match arm per opcode, as pickle.py reads",
    'worker/src/gesture/intervention.rs::choreography': "the 20 intervention gestures, one match arm each: a table",
    'worker/src/render/pipeline.rs::Pipeline::new': "wgpu's descriptors of the one render pipeline, declared in order",
}

# ---------------------------------------------------------------------------------------------
# Lexer


@dataclass(slots=True)
class Tok:
    kind: str  # 'id', 'p' (punctuation), 'str', 'chr', 'num', 'life'
    text: str
    line: int
    end: int  # last line the token covers (multi-line strings)


_RAW_STR = re.compile(r'(?:[bc]?r)(#*)"')
_MULTI_PUNCT = ('...', '..=', '::', '->', '=>', '==', '!=', '&&', '||', '..')


def _ident_start(c: str) -> bool:
    return c == '_' or c.isalpha()


def _ident_char(c: str) -> bool:
    return c == '_' or c.isalnum()


def lex(src: str) -> list[Tok]:
    """Rust source -> tokens, with comments dropped and literals kept as single tokens."""
    toks: list[Tok] = []
    i, n, line = 0, len(src), 1

    def string_end(q: int) -> int:  # q: index of the opening quote; returns index past the close
        j = q + 1
        while j < n:
            c = src[j]
            if c == '\\':
                j += 2
            elif c == '"':
                return j + 1
            else:
                j += 1
        return n

    def char_end(q: int) -> int:  # q: index of the opening '
        if q + 1 < n and src[q + 1] == '\\':
            j = src.find("'", q + 3)
            return n if j < 0 else j + 1
        return q + 3

    while i < n:
        c = src[i]
        if c == '\n':
            line += 1
            i += 1
            continue
        if c.isspace():
            i += 1
            continue
        if c == '/' and i + 1 < n and src[i + 1] == '/':
            j = src.find('\n', i)
            i = n if j < 0 else j
            continue
        if c == '/' and i + 1 < n and src[i + 1] == '*':
            depth, j = 1, i + 2
            while j < n and depth:
                if src.startswith('/*', j):
                    depth, j = depth + 1, j + 2
                elif src.startswith('*/', j):
                    depth, j = depth - 1, j + 2
                else:
                    j += 1
            line += src.count('\n', i, j)
            i = j
            continue
        start_line = line
        if c in 'rbc':
            m = _RAW_STR.match(src, i)
            if m:
                close = '"' + m.group(1)
                j = src.find(close, m.end())
                j = n if j < 0 else j + len(close)
                line += src.count('\n', i, j)
                toks.append(Tok('str', src[i:j], start_line, line))
                i = j
                continue
            if c in 'bc' and i + 1 < n and src[i + 1] == '"':
                j = string_end(i + 1)
                line += src.count('\n', i, j)
                toks.append(Tok('str', src[i:j], start_line, line))
                i = j
                continue
            if c == 'b' and i + 1 < n and src[i + 1] == "'":
                j = char_end(i + 1)
                toks.append(Tok('chr', src[i:j], line, line))
                i = j
                continue
            if c == 'r' and src.startswith('r#', i) and i + 2 < n and _ident_start(src[i + 2]):
                j = i + 2
                while j < n and _ident_char(src[j]):
                    j += 1
                toks.append(Tok('id', src[i + 2:j], line, line))
                i = j
                continue
        if c == '"':
            j = string_end(i)
            line += src.count('\n', i, j)
            toks.append(Tok('str', src[i:j], start_line, line))
            i = j
            continue
        if c == "'":
            if i + 1 < n and src[i + 1] == '\\':
                j = char_end(i)
                toks.append(Tok('chr', src[i:j], line, line))
                i = j
                continue
            if i + 2 < n and src[i + 2] == "'" and src[i + 1] != '\n':
                toks.append(Tok('chr', src[i:i + 3], line, line))
                i += 3
                continue
            j = i + 1
            while j < n and _ident_char(src[j]):
                j += 1
            toks.append(Tok('life' if j > i + 1 else 'p', src[i:j], line, line))
            i = j
            continue
        if _ident_start(c):
            j = i + 1
            while j < n and _ident_char(src[j]):
                j += 1
            toks.append(Tok('id', src[i:j], line, line))
            i = j
            continue
        if c.isdigit():
            j = i + 1
            while j < n and _ident_char(src[j]):
                j += 1
            if j + 1 < n and src[j] == '.' and src[j + 1].isdigit():
                j += 1
                while j < n and _ident_char(src[j]):
                    j += 1
            if src[j - 1] in 'eE' and j < n and src[j] in '+-' and not src.startswith(('0x', '0X'), i):
                j += 1
                while j < n and _ident_char(src[j]):
                    j += 1
            toks.append(Tok('num', src[i:j], line, line))
            i = j
            continue
        for p in _MULTI_PUNCT:
            if src.startswith(p, i):
                toks.append(Tok('p', p, line, line))
                i += len(p)
                break
        else:
            toks.append(Tok('p', c, line, line))
            i += 1
    return toks


def match_brackets(toks: list[Tok]) -> list[int]:
    """For each ( [ { token, the index of its closing token (-1 elsewhere); lenient on errors."""
    pairs = {')': '(', ']': '[', '}': '{'}
    match = [-1] * len(toks)
    stack: list[int] = []
    for k, t in enumerate(toks):
        if t.kind != 'p':
            continue
        if t.text in '([{':
            stack.append(k)
        elif t.text in pairs:
            want = pairs[t.text]
            if any(toks[s].text == want for s in stack):
                while stack:
                    s = stack.pop()
                    match[s] = k
                    if toks[s].text == want:
                        break
    for s in stack:
        match[s] = len(toks) - 1
    return match


# ---------------------------------------------------------------------------------------------
# Module tree


@dataclass(eq=False)
class Item:
    kind: str
    name: str
    file: str


@dataclass(eq=False)
class UseEntry:
    segs: list[str]
    alias: str | None  # None for a glob
    glob: bool
    pub: bool
    line: int
    label: str | None  # the fn/item holding a `use` inside a body
    module: 'Module'

    @property
    def text(self) -> str:
        s = '::'.join(self.segs) + ('::*' if self.glob else '')
        if not self.glob and self.alias and self.alias != (self.segs[-1] if self.segs else None):
            s += f' as {self.alias}'
        return s


@dataclass(eq=False)
class Module:
    name: str
    file: str  # workspace-relative path of the file holding it
    parent: 'Module | None'
    crate: 'CrateTree'
    child_dir: Path  # where the files of its `mod x;` children live
    defs: dict[str, Item] = field(default_factory=dict)
    children: dict[str, 'Module'] = field(default_factory=dict)
    imports: dict[str, list[UseEntry]] = field(default_factory=dict)
    globs: list[UseEntry] = field(default_factory=list)
    uses: list[UseEntry] = field(default_factory=list)
    paths: list[tuple[list[str], int, str]] = field(default_factory=list)
    idents: dict[str, str] = field(default_factory=dict)  # name in code -> first item using it
    heads: set[str] = field(default_factory=set)  # first segments of multi-segment paths

    def walk(self):
        yield self
        for c in self.children.values():
            yield from c.walk()


@dataclass(eq=False)
class CrateTree:
    package: 'Package'
    kind: str  # lib, bin, test, bench, example, build
    root_file: Path
    lib: 'CrateTree | None' = None  # the package's library, for the other targets
    root: Module | None = None
    loaded: set[Path] = field(default_factory=set)
    macros: list[Item] = field(default_factory=list)  # #[macro_export] macro_rules, at the root


@dataclass(eq=False)
class Package:
    name: str  # package name
    lib_name: str
    dir: Path
    rel: str  # member directory, relative to the workspace root
    trees: list[CrateTree] = field(default_factory=list)


KEYWORDS_QUAL = ('default', 'unsafe', 'async', 'safe', 'auto')
MACRO_ITEM_KW = ('struct', 'enum', 'union', 'trait', 'type', 'const', 'static')
# what may follow a #[cfg(test)] inside a body for the script to skip it as test code
STMT_START = ('use', 'let', 'fn', 'mod', 'impl', 'struct', 'enum', 'const', 'static', 'type', 'trait',
              'pub', '{')


class Analyzer:
    def __init__(self, root: Path):
        self.root = root.resolve()
        self._lexed: dict[Path, tuple[list[Tok], list[int]]] = {}
        self.test_files: set[Path] = set()
        self.test_spans: dict[Path, list[tuple[int, int]]] = {}
        self.packages: list[Package] = []
        # (src, dst) -> list of (priority, line, text)
        self.edges: dict[tuple[str, str], list[tuple[int, int, str]]] = defaultdict(list)
        # (file, first line) -> (name with its owner, lines of code of its body)
        self.fns: dict[tuple[Path, int], tuple[str, int]] = {}

    # -- files --------------------------------------------------------------------------------
    def rel(self, p: Path) -> str:
        try:
            return p.resolve().relative_to(self.root).as_posix()
        except ValueError:
            return p.as_posix()

    def lexed(self, p: Path) -> tuple[list[Tok], list[int]]:
        p = p.resolve()
        if p not in self._lexed:
            src = p.read_text(encoding='utf-8', errors='replace')
            toks = lex(src)
            self._lexed[p] = (toks, match_brackets(toks))
        return self._lexed[p]

    # -- workspace ----------------------------------------------------------------------------
    def discover(self):
        manifest_path = self.root / 'Cargo.toml'
        if not manifest_path.is_file():
            raise SystemExit(f'error: no Cargo.toml in {self.root}')
        manifest = tomllib.loads(manifest_path.read_text())
        dirs: list[Path] = []
        ws = manifest.get('workspace', {})
        excluded = {(self.root / e).resolve() for e in ws.get('exclude', [])}
        for pat in ws.get('members', []):
            for d in sorted(globmod.glob(str(self.root / pat))):
                d = Path(d).resolve()
                if (d / 'Cargo.toml').is_file() and d not in excluded and d not in dirs:
                    dirs.append(d)
        if 'package' in manifest and self.root not in dirs:
            dirs.insert(0, self.root)
        for d in dirs:
            self.packages.append(self.load_package(d))

    def load_package(self, d: Path) -> Package:
        m = tomllib.loads((d / 'Cargo.toml').read_text())
        pkg = m.get('package', {})
        name = pkg.get('name', d.name)
        lib = m.get('lib', {})
        package = Package(name, lib.get('name', name).replace('-', '_'), d, self.rel(d) or '.')
        seen: set[Path] = set()

        def add(kind: str, p: Path | None, lib_tree: CrateTree | None):
            if p is None or not p.is_file() or p.resolve() in seen:
                return None
            seen.add(p.resolve())
            t = CrateTree(package, kind, p.resolve(), lib_tree)
            package.trees.append(t)
            return t

        lib_tree = add('lib', d / lib['path'] if 'path' in lib else d / 'src/lib.rs', None)

        def targets(key: str, auto: bool, dirname: str, default: Path | None = None):
            out: list[Path] = []
            for t in m.get(key, []):
                if 'path' in t:
                    out.append(d / t['path'])
                elif 'name' in t:
                    cands = [d / dirname / f"{t['name']}.rs", d / dirname / t['name'] / 'main.rs']
                    if key == 'bin' and t['name'] == name:
                        cands.insert(0, d / 'src/main.rs')
                    out.extend(c for c in cands if c.is_file())
            if auto:
                if default is not None:
                    out.append(default)
                out.extend(sorted((d / dirname).glob('*.rs')))
                out.extend(sorted((d / dirname).glob('*/main.rs')))
            return out

        for p in targets('bin', pkg.get('autobins', True), 'src/bin', d / 'src/main.rs'):
            add('bin', p, lib_tree)
        for p in targets('test', pkg.get('autotests', True), 'tests'):
            add('test', p, lib_tree)
        for p in targets('bench', pkg.get('autobenches', True), 'benches'):
            add('bench', p, lib_tree)
        for p in targets('example', pkg.get('autoexamples', True), 'examples'):
            add('example', p, lib_tree)
        build = pkg.get('build', True)
        if build is not False:
            add('build', d / (build if isinstance(build, str) else 'build.rs'), None)
        for t in package.trees:
            t.root = self.load_module(t.root_file, 'crate', None, t, t.root_file.parent)
            for m in t.macros:
                t.root.defs.setdefault(m.name, m)
        return package

    def load_module(self, path: Path, name: str, parent: Module | None, tree: CrateTree,
                    child_dir: Path) -> Module:
        mod = Module(name, self.rel(path), parent, tree, child_dir)
        path = path.resolve()
        if path in tree.loaded:  # a #[path] loop
            return mod
        tree.loaded.add(path)
        toks, match = self.lexed(path)
        Parser(self, toks, match, path).parse_items(0, len(toks), mod, None)
        return mod

    def child_file(self, mod: Module, name: str, path_attr: str | None, in_inline: bool,
                   src_file: Path) -> tuple[Path | None, Path]:
        if path_attr:
            base = mod.child_dir if in_inline else src_file.parent
            p = (base / path_attr).resolve()
            return (p if p.is_file() else None), (p.parent if p.name == 'mod.rs' else p.with_suffix(''))
        for p in (mod.child_dir / f'{name}.rs', mod.child_dir / name / 'mod.rs'):
            if p.is_file():
                return p.resolve(), mod.child_dir / name
        return None, mod.child_dir / name

    def mark_test_file(self, p: Path, child_dir: Path, depth: int = 0):
        """A `#[cfg(test)] mod x;` file: all of it, and the files of its own `mod` items, are test code."""
        p = p.resolve()
        if p in self.test_files or depth > 20:
            return
        self.test_files.add(p)
        toks, _ = self.lexed(p)
        for k in range(len(toks) - 2):
            if toks[k].text == 'mod' and toks[k + 1].kind == 'id' and toks[k + 2].text == ';':
                nm = toks[k + 1].text
                for c in (child_dir / f'{nm}.rs', child_dir / nm / 'mod.rs'):
                    if c.is_file():
                        self.mark_test_file(c, child_dir / nm, depth + 1)
                        break

    # -- resolution ---------------------------------------------------------------------------
    def lookup(self, mod: Module, name: str, want_module: bool, seen: set) -> Module | Item | None:
        """`name` as a member of module `mod` (its items, child modules, imports, globs)."""
        key = (id(mod), name, want_module)
        if key in seen or len(seen) > 200:
            return None
        seen = seen | {key}
        order = ('children', 'imports', 'defs') if want_module else ('defs', 'children', 'imports')
        for where in order:
            if where == 'defs' and name in mod.defs:
                return mod.defs[name]
            if where == 'children' and name in mod.children:
                return mod.children[name]
            if where == 'imports':
                for e in mod.imports.get(name, ()):
                    t = self.resolve(e.module, e.segs, seen)
                    if t is not None:
                        return t
        for g in mod.globs:
            t = self.resolve(g.module, g.segs, seen)
            if isinstance(t, Module):
                r = self.lookup(t, name, want_module, seen)
                if r is not None:
                    return r
        return None

    def resolve(self, mod: Module, segs: list[str], seen: set | None = None) -> Module | Item | None:
        """A path as written in module `mod` -> the module or item it names, or None."""
        seen = seen or set()
        if not segs:
            return None
        head, rest = segs[0], segs[1:]
        cur: Module | Item | None
        if head == 'crate':
            cur = mod.crate.root
        elif head == 'self':
            cur = mod
        elif head == 'super':
            cur = mod.parent
        elif head in ('::', 'Self'):
            return None
        else:
            cur = self.lookup(mod, head, bool(rest), seen)
            if cur is None and mod.crate.lib is not None and head == mod.crate.package.lib_name:
                cur = mod.crate.lib.root
        for k, s in enumerate(rest):
            if cur is None:
                return None
            if isinstance(cur, Item):
                return cur  # an associated item or an enum variant of `cur`
            if s == 'super':
                cur = cur.parent
            elif s != 'self':
                cur = self.lookup(cur, s, k < len(rest) - 1, seen)
        return cur

    def exported(self, mod: Module, seen: set | None = None) -> set[str]:
        seen = seen if seen is not None else set()
        if id(mod) in seen:
            return set()
        seen.add(id(mod))
        names = set(mod.defs) | set(mod.children) | set(mod.imports)
        for g in mod.globs:
            t = self.resolve(g.module, g.segs)
            if isinstance(t, Module):
                names |= self.exported(t, seen)
        return names

    # -- edges --------------------------------------------------------------------------------
    def add_edge(self, src: str, dst: Module | Item, prio: int, line: int, text: str):
        dfile = dst.file
        if dfile != src:
            self.edges[(src, dfile)].append((prio, line, text))

    def build_edges(self):
        for pkg in self.packages:
            for tree in pkg.trees:
                for mod in tree.root.walk():
                    self.module_edges(mod)

    def module_edges(self, mod: Module):
        f = mod.file
        for segs, line, label in mod.paths:
            t = self.resolve(mod, segs)
            if t is not None:
                self.add_edge(f, t, 0, line, f"{label} uses {'::'.join(segs)}")
        for e in mod.uses:
            t = self.resolve(mod, e.segs)
            if t is None:
                continue
            if e.glob:
                if isinstance(t, Module):
                    used = sorted(n for n in self.exported(t) if n in mod.idents)
                    for n in used:
                        tt = self.lookup(t, n, False, set())
                        if tt is not None:
                            self.add_edge(f, tt, 0, e.line, f'{mod.idents[n]} uses {n} (use {e.text})')
                    if not used and not e.pub:
                        self.add_edge(f, t, 2, e.line, f'use {e.text}')
                elif not e.pub:
                    self.add_edge(f, t, 1, e.line, f'use {e.text}')
                continue
            user = e.label or mod.idents.get(e.alias or '')
            if isinstance(t, Module):
                if not e.pub and e.alias not in mod.heads:
                    self.add_edge(f, t, 2, e.line, f'use {e.text}')
                continue
            if e.pub and e.alias not in mod.idents:
                continue  # a facade: `pub use` of a name this module's code does not mention
            if user:
                self.add_edge(f, t, 0, e.line, f'{user} uses {e.text}')
            else:
                self.add_edge(f, t, 1, e.line, f'use {e.text}')


class Parser:
    def __init__(self, an: Analyzer, toks: list[Tok], match: list[int], path: Path):
        self.an, self.T, self.M, self.path = an, toks, match, path
        self.n = len(toks)
        an.test_spans.setdefault(path, [])

    def t(self, k: int) -> str:
        return self.T[k].text if 0 <= k < self.n else ''

    def close(self, k: int) -> int:
        m = self.M[k]
        return m if m >= 0 else self.n - 1

    # -- items --------------------------------------------------------------------------------
    def head(self, i: int, e: int) -> tuple[int, bool]:
        """Skips visibility and qualifiers; returns (index of the item keyword, is pub)."""
        j, pub = i, False
        if self.t(j) == 'pub':
            pub = True
            j += 1
            if self.t(j) == '(':
                j = self.close(j) + 1
        elif self.t(j) == 'crate' and self.t(j + 1) != '::':
            j += 1
        while j < e:
            x, nx = self.t(j), self.t(j + 1)
            if x in KEYWORDS_QUAL and j + 1 < self.n and self.T[j + 1].kind == 'id':
                j += 1
            elif x == 'const' and nx in ('fn', 'unsafe', 'async', 'extern'):
                j += 1
            elif x == 'extern' and j + 1 < self.n and self.T[j + 1].kind == 'str' and self.t(j + 2) in ('fn', 'unsafe'):
                j += 2
            elif x == 'extern' and nx == 'fn':
                j += 1
            else:
                break
        return j, pub

    def item_end(self, i: int, e: int) -> int:
        j, _ = self.head(i, e)
        kw, nx = self.t(j), self.t(j + 1)
        semi_only = kw in ('use', 'static', 'type', 'let') or (kw == 'const') or (kw == 'extern' and nx == 'crate')
        k = j
        while k < e:
            tk = self.T[k]
            if tk.kind == 'p':
                if tk.text in '([':
                    k = self.close(k) + 1
                    continue
                if tk.text == '{':
                    if semi_only:
                        k = self.close(k) + 1
                        continue
                    return min(self.close(k) + 1, e)
                if tk.text == ';':
                    return k + 1
            k += 1
        return e

    @staticmethod
    def cfg_test(texts: list[str]) -> bool:
        if texts[:2] != ['cfg', '('] or texts[-1:] != [')']:
            return False
        inner = texts[2:-1]
        if inner == ['test']:
            return True
        if inner[:2] == ['all', '('] and 'not' not in inner:
            args, cur, depth = [], [], 0
            for x in inner[2:-1]:
                if x == ',' and depth == 0:
                    args.append(cur)
                    cur = []
                    continue
                depth += x == '('
                depth -= x == ')'
                cur.append(x)
            args.append(cur)
            return ['test'] in args
        return False

    def parse_items(self, i: int, e: int, mod: Module, owner: str | None, in_inline: bool = False):
        T = self.T
        while i < e:
            start = i
            attrs: list[list[str]] = []
            path_attr = None
            macro_export = False
            while i < e and T[i].text == '#' and T[i].kind == 'p':
                j = i + 1
                inner = self.t(j) == '!'
                if inner:
                    j += 1
                if self.t(j) != '[':
                    break
                c = self.close(j)
                texts = [T[k].text for k in range(j + 1, c)]
                if inner:
                    if self.cfg_test(texts):  # #![cfg(test)]: the whole module is test code
                        self.an.test_spans[self.path].append((T[start].line, T[e - 1].end))
                        return
                else:
                    attrs.append(texts)
                    if texts[:2] == ['path', '='] and c - j > 3 and T[j + 3].kind == 'str':
                        path_attr = T[j + 3].text.split('"')[1]
                    macro_export |= texts[:1] == ['macro_export']
                i = c + 1
            if i >= e:
                break
            end = self.item_end(i, e)
            if any(self.cfg_test(a) for a in attrs):
                self.an.test_spans[self.path].append((T[start].line, T[end - 1].end))
                j, _ = self.head(i, e)
                if self.t(j) == 'mod' and self.t(j + 2) == ';' and owner is None:
                    f, cdir = self.an.child_file(mod, self.t(j + 1), path_attr, in_inline, self.path)
                    if f is not None:
                        self.an.mark_test_file(f, cdir)
                i = end
                continue
            self.parse_item(i, end, mod, owner, path_attr, macro_export, in_inline)
            i = max(end, i + 1)

    def body_brace(self, j: int, e: int) -> int:
        """Index of the first `{` at this level in [j, e), or -1."""
        k = j
        while k < e:
            tk = self.T[k]
            if tk.kind == 'p':
                if tk.text in '([':
                    k = self.close(k) + 1
                    continue
                if tk.text == '{':
                    return k
                if tk.text == ';':
                    return -1
            k += 1
        return -1

    def impl_name(self, j: int, b: int) -> str:
        k = j + 1
        if self.t(k) == '<':
            k = self.skip_angle(k, b) + 1
        fr = k
        for q in range(k, b):
            if self.t(q) == 'for' and self.T[q].kind == 'id':
                fr = q + 1
        name = '?'
        for q in range(fr, b):
            tk = self.T[q]
            if tk.kind == 'id' and tk.text not in ('dyn', 'mut', 'const', 'crate', 'super', 'self', 'impl'):
                name = tk.text
                if self.t(q + 1) != '::':
                    break
            elif tk.text in ('<', 'where', '{'):
                break
        return name

    def parse_item(self, i: int, e: int, mod: Module, owner: str | None, path_attr: str | None,
                   macro_export: bool, in_inline: bool):
        T = self.T
        j, pub = self.head(i, e)
        kw = self.t(j)
        nx = self.t(j + 1)
        name_ok = j + 1 < e and T[j + 1].kind == 'id'

        def define(name: str, kind: str):
            if owner is None and name != '_':
                mod.defs.setdefault(name, Item(kind, name, mod.file))

        if kw == 'use':
            semi = e - 1 if self.t(e - 1) == ';' else e
            self.parse_use(j + 1, semi, mod, pub and owner is None, None)
        elif kw == 'mod' and name_ok:
            name = nx
            if self.t(j + 2) == ';':
                f, cdir = self.an.child_file(mod, name, path_attr, in_inline, self.path)
                if f is not None and owner is None:
                    mod.children[name] = self.an.load_module(f, name, mod, mod.crate, cdir)
            elif self.t(j + 2) == '{':
                child = Module(name, mod.file, mod, mod.crate, mod.child_dir / name)
                if owner is None:
                    mod.children[name] = child
                self.parse_items(j + 3, self.close(j + 2), child, None, True)
        elif kw == 'fn' and name_ok:
            define(nx, 'fn')
            self.record_fn(j, e, f'{owner}::{nx}' if owner else nx)
            self.scan(j + 2, e, mod, f'{owner}::{nx}' if owner else nx)
        elif kw in ('struct', 'enum', 'union', 'type') and name_ok:
            define(nx, kw)
            self.scan(j + 2, e, mod, nx)
        elif kw == 'trait' and name_ok:
            define(nx, 'trait')
            b = self.body_brace(j + 2, e)
            if b < 0:
                self.scan(j + 2, e, mod, nx)
            else:
                self.scan(j + 2, b, mod, nx)
                self.parse_items(b + 1, self.close(b), mod, nx)
        elif kw == 'impl':
            b = self.body_brace(j + 1, e)
            label = self.impl_name(j, b if b >= 0 else e)
            if b < 0:
                self.scan(j + 1, e, mod, label)
            else:
                self.scan(j + 1, b, mod, label)
                self.parse_items(b + 1, self.close(b), mod, label)
        elif kw in ('const', 'static'):
            k = j + 1
            if self.t(k) == 'mut':
                k += 1
            if k < e and T[k].kind == 'id':
                define(T[k].text, kw)
                self.scan(k + 1, e, mod, f'{owner}::{T[k].text}' if owner else T[k].text)
        elif kw == 'macro_rules' and nx == '!' and j + 2 < e and T[j + 2].kind == 'id':
            name = T[j + 2].text
            define(name, 'macro')
            if macro_export and owner is None:  # #[macro_export]: `crate::name!`
                mod.crate.macros.append(Item('macro', name, mod.file))
            if owner is None:  # items the macro declares under a literal name (`pub enum Bone`)
                for k in range(j + 3, e - 1):
                    if (self.t(k) in MACRO_ITEM_KW and T[k + 1].kind == 'id' and self.t(k - 1) != '$'
                            and T[k + 1].text not in ('fn', 'mut', 'unsafe', 'async', 'extern')):
                        mod.defs.setdefault(T[k + 1].text, Item(f'{self.t(k)} (from {name}!)', T[k + 1].text, mod.file))
            self.scan(j + 3, e, mod, f'{name}!')
        elif kw == 'extern' and nx == 'crate':
            pass
        else:
            label = owner or (f'{kw}!' if nx == '!' else '(item)')
            self.scan(j, e, mod, label)

    def record_fn(self, j: int, e: int, name: str):
        b = self.body_brace(j + 2, e)
        if b < 0:
            return
        lines = set()
        for tk in self.T[b:self.close(b) + 1]:
            lines.update(range(tk.line, tk.end + 1))
        self.an.fns[(self.path, self.T[j].line)] = (name, len(lines))

    # -- code ---------------------------------------------------------------------------------
    def skip_angle(self, k: int, e: int) -> int:
        """k: index of `<`; returns the index of its `>` (or e - 1)."""
        depth = 0
        while k < e:
            x = self.T[k]
            if x.kind == 'p':
                if x.text == '<':
                    depth += 1
                elif x.text == '>':
                    depth -= 1
                    if depth == 0:
                        return k
                elif x.text in '([{':
                    k = self.close(k)
                elif x.text == ';':
                    return k
            k += 1
        return e - 1

    def scan(self, i: int, e: int, mod: Module, label: str):
        """Records the paths and names used by code in [i, e), and the `use`s inside bodies."""
        T = self.T
        j = i
        while j < e:
            tk = T[j]
            if tk.kind == 'id':
                x = tk.text
                if x == 'use':
                    k = j + 1
                    while k < e and not (T[k].kind == 'p' and T[k].text == ';'):
                        k = self.close(k) + 1 if T[k].kind == 'p' and T[k].text in '([{' else k + 1
                    self.parse_use(j + 1, min(k, e), mod, False, label)
                    j = k + 1
                    continue
                if x == 'pub' and self.t(j + 1) == '(':
                    j = self.close(j + 1) + 1
                    continue
                prev = T[j - 1] if j > 0 else None
                if prev is not None and prev.kind == 'p' and prev.text in ('.', '::'):
                    j += 1
                    continue
                if x == '$' or (prev is not None and prev.text == '$' and x != 'crate'):
                    j += 1  # a macro metavariable
                    continue
                segs = [x]
                k = j
                while k + 2 < e and self.t(k + 1) == '::':
                    nt = T[k + 2]
                    if nt.kind == 'id':
                        segs.append(nt.text)
                        k += 2
                    else:
                        break
                mod.idents.setdefault(x, label)
                if len(segs) >= 2:
                    mod.paths.append((segs, tk.line, label))
                    mod.heads.add(x)
                j = k + 1
                continue
            if tk.kind == 'p' and tk.text == '#' and self.t(j + 1) == '[':
                c = self.close(j + 1)
                if self.cfg_test([T[k].text for k in range(j + 2, c)]) and self.t(c + 1) in STMT_START:
                    # a #[cfg(test)] statement or item inside a body: test code
                    end = self.close(c + 1) + 1 if self.t(c + 1) == '{' else self.item_end(c + 1, e)
                    self.an.test_spans[self.path].append((tk.line, T[min(end, e) - 1].end))
                    j = end
                    continue
            if tk.kind == 'p' and tk.text == '::' and j + 1 < e and T[j + 1].kind == 'id' and (
                    j == 0 or T[j - 1].kind != 'id'):
                # `::abs::path` (another crate): skip it
                k = j
                while k + 1 < e and self.t(k) == '::' and T[k + 1].kind == 'id':
                    k += 2
                j = k
                continue
            j += 1

    def parse_use(self, i: int, e: int, mod: Module, pub: bool, label: str | None):
        T = self.T

        def add(segs: list[str], alias: str | None, glob: bool, line: int):
            ent = UseEntry(segs, alias, glob, pub, line, label, mod)
            mod.uses.append(ent)
            if glob:
                mod.globs.append(ent)
            elif alias and alias != '_':
                mod.imports.setdefault(alias, []).append(ent)

        def tree(k: int, prefix: list[str]) -> int:
            segs = list(prefix)
            if self.t(k) == '::' and not prefix:
                segs.append('::')
                k += 1
            while k + 1 < e and T[k].kind == 'id' and self.t(k + 1) == '::':
                segs.append(T[k].text)
                k += 2
            if k >= e:
                return e
            tk = T[k]
            if tk.text == '*':
                add(segs, None, True, tk.line)
                return k + 1
            if tk.text == '{' and tk.kind == 'p':
                c = min(self.close(k), e)
                q = k + 1
                while q < c:
                    if self.t(q) == ',':
                        q += 1
                        continue
                    nq = tree(q, segs)
                    q = nq if nq > q else q + 1
                return c + 1
            if tk.kind == 'id':
                k += 1
                if tk.text == 'self':
                    full = segs
                else:
                    full = segs + [tk.text]
                alias = full[-1] if full else None
                if self.t(k) == 'as' and k + 1 < e:
                    alias = T[k + 1].text
                    k += 2
                if full:
                    add(full, alias, False, tk.line)
                return k
            return k + 1

        k = i
        while k < e:
            nk = tree(k, [])
            k = nk if nk > k else k + 1
            if self.t(k) == ',':
                k += 1


# ---------------------------------------------------------------------------------------------
# Checks


def sccs(nodes: list[str], edges: dict[str, set[str]]) -> list[list[str]]:
    """Tarjan's strongly connected components (iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    on: set[str] = set()
    stack: list[str] = []
    out: list[list[str]] = []
    counter = 0
    for s in nodes:
        if s in index:
            continue
        work = [(s, iter(sorted(edges.get(s, ()))))]
        index[s] = low[s] = counter
        counter += 1
        stack.append(s)
        on.add(s)
        while work:
            v, it = work[-1]
            advanced = False
            for w in it:
                if w not in index:
                    index[w] = low[w] = counter
                    counter += 1
                    stack.append(w)
                    on.add(w)
                    work.append((w, iter(sorted(edges.get(w, ())))))
                    advanced = True
                    break
                if w in on:
                    low[v] = min(low[v], index[w])
            if advanced:
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                comp = []
                while True:
                    w = stack.pop()
                    on.discard(w)
                    comp.append(w)
                    if w == v:
                        break
                out.append(sorted(comp))
    return out


def package_files(an: Analyzer, pkg: Package) -> list[Path]:
    nested = {p.dir for p in an.packages if p.dir != pkg.dir}
    out = []
    for dirpath, dirnames, filenames in os.walk(pkg.dir):
        d = Path(dirpath)
        dirnames[:] = sorted(x for x in dirnames
                             if not x.startswith('.') and x != 'target' and (d / x) not in nested)
        out.extend(d / f for f in sorted(filenames) if f.endswith('.rs'))
    return out


def line_counts(an: Analyzer, p: Path) -> tuple[int, int]:
    """(total lines, non-test code lines) of a file."""
    p = p.resolve()
    src = p.read_text(encoding='utf-8', errors='replace')
    total = src.count('\n') + (0 if src.endswith('\n') or not src else 1)
    if p in an.test_files:
        return total, 0
    toks, match = an.lexed(p)
    if p not in an.test_spans:  # not in any module tree: parse it alone for its test items
        pkg = Package('?', '?', p.parent, '?')
        tree = CrateTree(pkg, 'orphan', p)
        tree.root = Module('crate', an.rel(p), None, tree, Path('/nonexistent'))
        Parser(an, toks, match, p).parse_items(0, len(toks), tree.root, None)
    code: set[int] = set()
    for t in toks:
        code.update(range(t.line, t.end + 1))
    for a, b in an.test_spans.get(p, ()):
        code.difference_update(range(a, b + 1))
    return total, len(code)


def line_limit(rel: str) -> int:
    """The most non-test lines the file at `rel` (relative to the workspace root) may hold."""
    under = [d for d in MAX_LINES_UNDER if rel.startswith(d.rstrip('/') + '/')]
    return MAX_LINES_UNDER[max(under, key=len)] if under else MAX_LINES


def crowded_folders(root: Path) -> list[tuple[str, int, int]]:
    """(folder, .rs files in it, limit) for each folder over its MAX_FILES_UNDER limit."""
    out = []
    for top, limit in sorted(MAX_FILES_UNDER.items()):
        for dirpath, dirnames, filenames in os.walk(root / top):
            dirnames[:] = sorted(x for x in dirnames if not x.startswith('.') and x != 'target')
            n = sum(1 for f in filenames if f.endswith('.rs'))
            if n > limit:
                out.append((Path(dirpath).relative_to(root).as_posix(), n, limit))
    return out


def long_fns(an: Analyzer, limit: int) -> list[tuple[str, int]]:
    """('path::name', lines) of the functions under a package's src/ over `limit` lines, longest first."""
    srcs = [p.dir / 'src' for p in an.packages]
    out = []
    for (path, _line), (name, n) in an.fns.items():
        if n > limit and any(path.is_relative_to(d) for d in srcs) and path not in an.test_files:
            out.append((f'{an.rel(path)}::{name}', n))
    return sorted(out, key=lambda x: (-x[1], x[0]))


def limits_text() -> str:
    stricter = ''.join(f'; {n} under {d.rstrip("/")}/' for d, n in sorted(MAX_LINES_UNDER.items()))
    return f'{MAX_LINES}{stricter}'


def analyze(root: Path) -> Analyzer:
    an = Analyzer(root)
    an.discover()
    an.build_edges()
    return an


def package_graph(an: Analyzer, pkg: Package):
    prefix = '' if pkg.rel == '.' else pkg.rel + '/'
    files = sorted({m.file for t in pkg.trees for m in t.root.walk()})
    adj: dict[str, set[str]] = defaultdict(set)
    ev: dict[tuple[str, str], list] = {}
    for (a, b), evid in an.edges.items():
        if a in files and b in files and (a.startswith(prefix) or not prefix):
            adj[a].add(b)
            ev[(a, b)] = sorted(evid)
    return files, adj, ev


def fmt_edge(a: str, b: str, evid: list) -> str:
    prio, line, text = evid[0]
    more = f', +{len(evid) - 1} more' if len(evid) > 1 else ''
    return f'{a} -> {b} ({text}; line {line}{more})'


def find_package(an: Analyzer, name: str) -> Package | None:
    for p in an.packages:
        if name in (p.name, p.lib_name, p.rel, p.dir.name):
            return p
    return None


# ---------------------------------------------------------------------------------------------
# Rule 4: relative Markdown links


# Folders not searched for Markdown files: build outputs, data, runs, hidden folders.
MD_SKIP_DIRS = {'target', 'node_modules', 'runs', 'data', 'encoders', '__pycache__'}

_MD_LINK = re.compile(r'!?\[(?:[^\[\]]|\[[^\[\]]*\])*\]\(\s*<?([^)\s>]+)>?(?:\s+"[^"]*")?\s*\)')
_MD_REF = re.compile(r'^\s{0,3}\[[^\]]+\]:\s+<?(\S+?)>?(?:\s+"[^"]*")?\s*$')
_MD_HEADING = re.compile(r'^\s{0,3}(#{1,6})\s+(.*?)\s*#*\s*$')


def markdown_files(root: Path) -> list[Path]:
    found = []
    for d, dirs, files in os.walk(root):
        dirs[:] = sorted(x for x in dirs if not x.startswith('.') and x not in MD_SKIP_DIRS)
        found += [Path(d) / f for f in sorted(files) if f.endswith('.md')]
    return found


def _md_prose_lines(text: str):
    """(line number, line with inline code removed) of the lines outside fenced code blocks."""
    fence = None
    for n, line in enumerate(text.split('\n'), 1):
        m = re.match(r'^\s{0,3}(`{3,}|~{3,})', line)
        if m:
            if fence is None:
                fence = m.group(1)[0] * len(m.group(1))
            elif m.group(1).startswith(fence):
                fence = None
            continue
        if fence is None:
            yield n, re.sub(r'(`+)(?:(?!\1).)+?\1', '', line)


def github_slug(heading: str) -> str:
    h = re.sub(r'!?\[([^\]]*)\]\([^)]*\)', r'\1', heading).strip().lower()
    return ''.join(c for c in h if c.isalnum() or c in ' -_').replace(' ', '-')


def markdown_anchors(text: str) -> set[str]:
    seen: dict[str, int] = {}
    out = set()
    for _, line in _md_prose_lines(text.replace('`', '')):
        m = _MD_HEADING.match(line)
        if not m:
            continue
        slug = github_slug(m.group(2))
        k = seen.get(slug, 0)
        seen[slug] = k + 1
        out.add(slug if k == 0 else f'{slug}-{k}')
    return out


def broken_links(root: Path) -> list[str]:
    """'file:line: target (why)' for each relative Markdown link that does not resolve."""
    anchors: dict[Path, set[str]] = {}
    bad = []
    for md in markdown_files(root):
        text = md.read_text(errors='replace')
        for n, line in _md_prose_lines(text):
            targets = [m.group(1) for m in _MD_LINK.finditer(line)]
            m = _MD_REF.match(line)
            if m:
                targets.append(m.group(1))
            for t in targets:
                if re.match(r'^[a-zA-Z][a-zA-Z0-9+.-]*:', t) or t.startswith('//'):
                    continue
                path, _, frag = t.partition('#')
                target = (md.parent / path).resolve() if path else md
                where = f'{md.relative_to(root)}:{n}: {t}'
                if path.startswith('/') or not target.exists():
                    bad.append(f'{where} (no such file)')
                elif frag and target.suffix == '.md' and target.is_file():
                    if target not in anchors:
                        anchors[target] = markdown_anchors(target.read_text(errors='replace'))
                    if frag.lower() not in anchors[target]:
                        bad.append(f'{where} (no such heading)')
    return bad


def run_checks(root: Path, out=sys.stdout) -> int:
    an = analyze(root)
    cycles = []
    n_files = 0
    for pkg in an.packages:
        files, adj, ev = package_graph(an, pkg)
        n_files += len(files)
        for comp in sccs(files, adj):
            if len(comp) > 1:
                cs = set(comp)
                inner = [(a, b) for a in comp for b in sorted(adj.get(a, ())) if b in cs]
                cycles.append((pkg, comp, [fmt_edge(a, b, ev[(a, b)]) for a, b in inner]))
    big = []
    stale = []
    for pkg in an.packages:
        for p in package_files(an, pkg):
            rel = an.rel(p)
            total, nt = line_counts(an, p)
            if nt > line_limit(rel) and rel not in SIZE_ALLOWLIST:
                big.append((rel, nt, total))
            elif rel in SIZE_ALLOWLIST and nt <= line_limit(rel):
                stale.append((rel, nt))
    for rel in SIZE_ALLOWLIST:
        if not (an.root / rel).is_file():
            stale.append((rel, None))
    w = out.write
    if cycles:
        w(f'import cycles ({len(cycles)}):\n')
        for pkg, comp, lines in cycles:
            w(f'  {pkg.name}: {len(comp)} files\n')
            for f in comp:
                w(f'    {f}\n')
            w('   edges inside it:\n')
            for line in lines:
                w(f'    {line}\n')
    if big:
        w(f'files over their limit of non-test lines ({len(big)}):\n')
        for rel, nt, total in sorted(big, key=lambda x: -x[1]):
            w(f'  {rel}: {nt} non-test lines ({total} in all; limit {line_limit(rel)})\n')
    crowded = crowded_folders(an.root)
    if crowded:
        w(f'folders over their limit of source files ({len(crowded)}):\n')
        for rel, n, limit in crowded:
            w(f'  {rel}/: {n} .rs files (limit {limit})\n')
    for rel, nt in stale:
        w(f'note: SIZE_ALLOWLIST entry {rel} is {"missing" if nt is None else f"at {nt} lines, under the limit"}; remove it\n')
    fns = [(k, n) for k, n in long_fns(an, MAX_FN_LINES) if k not in FN_ALLOWLIST]
    if fns:
        w(f'functions over {MAX_FN_LINES} lines of code ({len(fns)}):\n')
        for k, n in fns:
            w(f'  {k}: {n} lines\n')
    listed = {k for k, _ in long_fns(an, MAX_FN_LINES)}
    for k in FN_ALLOWLIST:
        if k not in listed:
            w(f'note: FN_ALLOWLIST entry {k} is missing or within {MAX_FN_LINES} lines; remove it\n')
    links = broken_links(an.root)
    if links:
        w(f'Markdown links that do not resolve ({len(links)}):\n')
        for line in links:
            w(f'  {line}\n')
    if cycles or big or crowded or fns or links:
        w(f'FAIL: {len(cycles)} import cycle(s), {len(big)} file(s) over their non-test line limit '
          f'({limits_text()}), {len(crowded)} folder(s) over their file limit, '
          f'{len(fns)} function(s) over {MAX_FN_LINES} lines, {len(links)} broken Markdown link(s)\n')
        return 1
    folders = ', '.join(f'{n} .rs files per folder under {d}/' for d, n in sorted(MAX_FILES_UNDER.items()))
    w(f'ok: {len(an.packages)} crates, {n_files} files, no import cycles, '
      f'no file over its non-test line limit ({limits_text()}), at most {folders}, '
      f'no function over {MAX_FN_LINES} lines ({len(FN_ALLOWLIST)} named exceptions), '
      f'every relative Markdown link resolves\n')
    return 0


def print_graph(root: Path, crate: str, out=sys.stdout) -> int:
    an = analyze(root)
    pkg = find_package(an, crate)
    if pkg is None:
        out.write(f'error: no crate {crate!r}; crates: {", ".join(p.name for p in an.packages)}\n')
        return 2
    files, adj, ev = package_graph(an, pkg)
    out.write(f'{pkg.name}: {len(files)} files, targets: '
              f'{", ".join(f"{t.kind} {an.rel(t.root_file)}" for t in pkg.trees)}\n')
    for a in files:
        for b in sorted(adj.get(a, ())):
            out.write(f'  {fmt_edge(a, b, ev[(a, b)])}\n')
    return 0


def print_sizes(root: Path, out=sys.stdout) -> int:
    an = analyze(root)
    rows = []
    for pkg in an.packages:
        for p in package_files(an, pkg):
            total, nt = line_counts(an, p)
            if total > SIZES_OVER:
                rows.append((nt, total, an.rel(p)))
    out.write(f'{"non-test":>8} {"total":>6}  file (files over {SIZES_OVER} lines; non-test limit {limits_text()})\n')
    for nt, total, rel in sorted(rows, reverse=True):
        flag = '  OVER' if nt > line_limit(rel) and rel not in SIZE_ALLOWLIST else (
            '  allowlisted' if rel in SIZE_ALLOWLIST else '')
        out.write(f'{nt:>8} {total:>6}  {rel}{flag}\n')
    return 0


# ---------------------------------------------------------------------------------------------
# Self-tests


def _write(base: Path, files: dict[str, str]):
    for rel, text in files.items():
        p = base / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(text)


def _workspace(base: Path, crates: dict[str, dict[str, str]]):
    _write(base, {'Cargo.toml': '[workspace]\nmembers = [%s]\n' % ', '.join(f'"{c}"' for c in crates)})
    for c, files in crates.items():
        _write(base / c, {'Cargo.toml': f'[package]\nname = "{c}"\nversion = "0.1.0"\n', **files})


def self_test() -> int:
    import io
    failures = []
    # the mini-workspaces have none of the workspace's long functions
    saved = dict(FN_ALLOWLIST)
    FN_ALLOWLIST.clear()

    def check(name: str, cond: bool, detail: str = ''):
        print(f'  {"ok  " if cond else "FAIL"} {name}')
        if not cond:
            failures.append(name)
            if detail:
                print('       ' + detail.replace('\n', '\n       '))

    def edges_of(an: Analyzer) -> set[tuple[str, str]]:
        return set(an.edges)

    with tempfile.TemporaryDirectory() as tmp:
        base = Path(tmp)
        # 1. A two-file cycle, through a brace group and an inline path.
        ws = base / 'cycle'
        _workspace(ws, {'cyc': {
            'src/lib.rs': 'pub mod a;\npub mod b;\n',
            'src/a.rs': 'use crate::{b::{self, B as Bee}};\npub struct A;\npub fn f(_: Bee) {}\n',
            'src/b.rs': 'pub struct B;\npub fn g() -> crate::a::A { crate::a::A }\n',
        }})
        buf = io.StringIO()
        rc = run_checks(ws, buf)
        check('2-file cycle is found', rc == 1 and 'cyc/src/a.rs -> cyc/src/b.rs' in buf.getvalue()
              and 'cyc/src/b.rs -> cyc/src/a.rs (g uses crate::a::A' in buf.getvalue(), buf.getvalue())

        # 2. A re-export facade is not a dependency; a glob facade neither.
        ws = base / 'facade'
        _workspace(ws, {'fac': {
            'src/lib.rs': 'pub mod model;\npub mod user;\npub mod sub;\npub use model::Policy;\n'
                          'pub use sub::*;\npub struct Config;\n',
            'src/model.rs': 'pub struct Policy { pub c: crate::Config }\n'
                            'pub fn h() -> crate::Helper { crate::Helper }\n',
            'src/sub/mod.rs': 'mod deep;\npub use deep::Helper;\n',
            'src/sub/deep.rs': 'pub struct Helper;\n',
            'src/user.rs': 'use crate::Policy;\npub fn f(_: Policy) {}\n',
        }})
        buf = io.StringIO()
        rc = run_checks(ws, buf)
        an = analyze(ws)
        e = edges_of(an)
        check('re-export facade is not a cycle', rc == 0, buf.getvalue())
        check('facade followed to the defining file',
              ('fac/src/user.rs', 'fac/src/model.rs') in e and ('fac/src/user.rs', 'fac/src/lib.rs') not in e
              and ('fac/src/model.rs', 'fac/src/sub/deep.rs') in e and ('fac/src/lib.rs', 'fac/src/model.rs') not in e,
              repr(sorted(e)))

        # 3. cfg(test) code is ignored (inline module and file module), and strings/comments too.
        ws = base / 'cfgtest'
        _workspace(ws, {'ct': {
            'src/lib.rs': 'pub mod a;\npub mod b;\n',
            'src/a.rs': 'pub struct A;\n#[cfg(test)]\nmod tests {\n    use crate::b::B;\n}\n'
                        '#[cfg(test)]\nmod more;\n'
                        '/// use crate::b::B;\n/* crate::b::B /* nested */ crate::b::B */\n'
                        'pub const S: &str = "crate::b::B";\npub const R: &str = r#"x "crate::b::B" y"#;\n'
                        "pub fn c<'a>(x: &'a str) -> char { let _ = '{'; let _ = '\\''; x.len(); 'z' }\n"
                        'pub fn after() -> crate::a::A { #[cfg(test)] use crate::b::B; A }\n'
                        '#[cfg(test)]\nfn helper() -> crate::b::B { todo!() }\n'
                        'impl A {\n    #[cfg(test)]\n    fn m() -> crate::b::B { todo!() }\n}\n',
            'src/a/more.rs': 'use crate::b::B;\nfn t() -> B { B }\n',
            'src/b.rs': 'use crate::a::A;\npub struct B(pub A);\n',
        }})
        buf = io.StringIO()
        rc = run_checks(ws, buf)
        an = analyze(ws)
        check('cfg(test) uses, comments and strings are ignored', rc == 0, buf.getvalue())
        check('cfg(test) mod file is marked test', (ws / 'ct/src/a/more.rs').resolve() in an.test_files)
        check('lexer keeps braces balanced after chars/lifetimes/raw strings',
              'after' in [d.name for m in an.packages[0].trees[0].root.walk() for d in m.defs.values()])

        # 4. Brace groups: nested, self, as, glob; a bin naming the library by its crate name.
        ws = base / 'braces'
        _workspace(ws, {'br': {
            'src/lib.rs': 'pub mod a;\npub mod b;\npub mod c;\npub mod d;\npub mod e;\n',
            'src/a.rs': 'use crate::{b::{self as bee, X as Y}, c::*, d::{self}};\n'
                        'pub fn f(_: Y) { bee::g(); let _ = CVAL; d::h(); }\n',
            'src/b.rs': 'pub struct X;\npub fn g() {}\n',
            'src/c.rs': 'pub const CVAL: u8 = 1;\n',
            'src/d.rs': 'pub fn h() {}\nmacro_rules! kinds { ($($n:ident),*) => { pub enum Kind { $($n),* } } }\n'
                        'kinds!(A, B);\n',
            'src/e.rs': 'pub fn unused() {}\n',
            'src/main.rs': 'use br::e::unused;\nfn main() { unused(); let _ = br::d::Kind::A; }\n',
        }})
        an = analyze(ws)
        e = edges_of(an)
        want = {('br/src/a.rs', 'br/src/b.rs'), ('br/src/a.rs', 'br/src/c.rs'),
                ('br/src/a.rs', 'br/src/d.rs'), ('br/src/main.rs', 'br/src/e.rs'), ('br/src/main.rs', 'br/src/d.rs')}
        check('brace groups (nested, self, as, glob), crate-name paths in a bin, macro-made items', want <= e,
              f'missing {sorted(want - e)}; have {sorted(e)}')
        check('no spurious edges in the brace-group crate', e <= want, f'extra {sorted(e - want)}')

        # 5. Size rule: non-test lines only.
        ws = base / 'size'
        body = ''.join(f'pub const C{k}: u32 = {k};\n' for k in range(MAX_LINES + 1))
        small = ''.join(f'pub const C{k}: u32 = {k};\n\n// c\n' for k in range(MAX_LINES - 1))
        tests = '#[cfg(test)]\nmod tests {\n' + ''.join(f'    const T{k}: u32 = 0;\n' for k in range(50)) + '}\n'
        _workspace(ws, {'sz': {'src/lib.rs': 'mod big;\nmod ok;\n', 'src/big.rs': body, 'src/ok.rs': small + tests}})
        buf = io.StringIO()
        rc = run_checks(ws, buf)
        check('file over the limit is reported with its count',
              rc == 1 and f'sz/src/big.rs: {MAX_LINES + 1} non-test lines' in buf.getvalue()
              and 'ok.rs' not in buf.getvalue(), buf.getvalue())

        # 6. A stricter folder: 500 non-test lines per file and 12 .rs files per folder under
        #    orchestrator/src (the limits of MAX_LINES_UNDER and MAX_FILES_UNDER).
        ws = base / 'strict'
        lim = line_limit('orchestrator/src/x.rs')
        over = ''.join(f'pub const C{k}: u32 = {k};\n' for k in range(lim + 1))
        at = ''.join(f'pub const C{k}: u32 = {k};\n' for k in range(lim))
        many = {f'src/many/m{k}.rs': '' for k in range(MAX_FILES_UNDER['orchestrator/src'])}
        enough = {f'src/enough/e{k}.rs': '' for k in range(MAX_FILES_UNDER['orchestrator/src'] - 1)}
        _workspace(ws, {'orchestrator': {
            'src/lib.rs': 'mod over;\nmod at;\nmod many;\nmod enough;\n', 'src/over.rs': over, 'src/at.rs': at,
            'src/many/mod.rs': '', **many, 'src/enough/mod.rs': '', **enough,
        }})
        buf = io.StringIO()
        rc = run_checks(ws, buf)
        text = buf.getvalue()
        check('a stricter folder: its line limit and its file limit per folder',
              rc == 1 and lim < MAX_LINES and f'orchestrator/src/over.rs: {lim + 1} non-test lines' in text
              and 'at.rs' not in text
              and f'orchestrator/src/many/: {MAX_FILES_UNDER["orchestrator/src"] + 1} .rs files' in text
              and 'enough' not in text and 'orchestrator/src/:' not in text, text)

        # 7. Clean workspace summary.
        ws = base / 'clean'
        _workspace(ws, {'cl': {'src/lib.rs': 'pub mod a;\n', 'src/a.rs': 'pub fn f() {}\n'}})
        buf = io.StringIO()
        rc = run_checks(ws, buf)
        check('clean workspace: exit 0 and one-line summary',
              rc == 0 and buf.getvalue().startswith('ok: 1 crates, 2 files'), buf.getvalue())

        # 8. Rule 4: relative Markdown links, outside code, with their anchors.
        ws = base / 'links'
        _workspace(ws, {'lk': {'src/lib.rs': ''}})
        _write(ws, {
            'README.md': '# Top\n\n## The study (1M, 5M)\n\n[ok](docs/a.md#part-two) [dir](docs/) '
                         '[self](#the-study-1m-5m) ![pic](docs/p.png) [web](https://x.org/y.md)\n'
                         '`[code](gone.md)`\n```sh\n[fenced](gone.md)\n```\n'
                         '[gone](docs/gone.md) [bad anchor](docs/a.md#nowhere)\n[ref]: docs/old.md\n',
            'docs/a.md': '# A\n## Part two\n[up](../README.md#top)\n',
            'docs/p.png': '',
        })
        buf = io.StringIO()
        rc = run_checks(ws, buf)
        text = buf.getvalue()
        check('broken Markdown links are reported, code and other sites are not',
              rc == 1 and 'README.md:10: docs/gone.md (no such file)' in text
              and 'README.md:10: docs/a.md#nowhere (no such heading)' in text
              and 'README.md:11: docs/old.md (no such file)' in text
              and '3 broken Markdown link(s)' in text and 'gone.md (' not in text.replace('docs/gone.md (', ''), text)

        # 9. Rule 5: function length, counted in lines of code, src/ only, test code skipped.
        ws = base / 'fns'
        body = lambda n: ''.join(f'    let x{k} = {k};\n\n    // why\n' for k in range(n - 2))
        long_fn = 'pub fn long() {\n' + body(MAX_FN_LINES + 1) + '}\n'
        _workspace(ws, {'fl': {
            'src/lib.rs': 'pub mod a;\n#[cfg(test)]\nmod tests {\n    fn t() {\n' + body(MAX_FN_LINES + 5) + '    }\n}\n',
            'src/a.rs': long_fn + 'pub struct S;\nimpl S {\n    pub fn fits(&self) {\n' + body(MAX_FN_LINES) + '    }\n'
                        '    pub fn over(&self) {\n' + body(MAX_FN_LINES + 2) + '    }\n}\n',
            'tests/it.rs': long_fn,
        }})
        buf = io.StringIO()
        rc = run_checks(ws, buf)
        text = buf.getvalue()
        check('functions over the limit are reported with their lines of code, src/ only',
              rc == 1 and f'fl/src/a.rs::long: {MAX_FN_LINES + 1} lines' in text
              and f'fl/src/a.rs::S::over: {MAX_FN_LINES + 2} lines' in text
              and 'fits' not in text and 'it.rs' not in text and 'lib.rs' not in text, text)

    FN_ALLOWLIST.update(saved)
    print('self-test: ' + ('ok' if not failures else f'{len(failures)} FAILED'))
    return 1 if failures else 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument('--root', type=Path, default=Path(__file__).resolve().parent.parent,
                    help='workspace root (default: the checkout holding this script)')
    ap.add_argument('--graph', metavar='CRATE', help="print the crate's file dependency edges")
    ap.add_argument('--sizes', action='store_true',
                    help=f'print the non-test line counts of the files over {SIZES_OVER} lines')
    ap.add_argument('--fns', metavar='N', type=int, nargs='?', const=60,
                    help='print the functions under src/ over N lines of code (default 60)')
    ap.add_argument('--self-test', action='store_true', help="run the script's own tests")
    a = ap.parse_args(argv)
    if a.self_test:
        return self_test()
    if a.graph:
        return print_graph(a.root, a.graph)
    if a.sizes:
        return print_sizes(a.root)
    if a.fns is not None:
        for k, n in long_fns(analyze(a.root), a.fns):
            print(f'{n:5d}  {k}{"  (allowed)" if k in FN_ALLOWLIST else ""}')
        return 0
    return run_checks(a.root)


if __name__ == '__main__':
    try:
        sys.exit(main())
    except BrokenPipeError:  # `| head`
        sys.stderr.close()
        sys.exit(0)
