"""Property tests of invalid input: generated configs (as dicts and as YAML files), command lines and study files.

The contract under test (docs/contract.md, docs/study.md): bad input ends with exit code 2 and one message on
stderr, never a traceback; good input gives 0; nothing is written outside the folder the command works in; a
study file never imports or calls code outside the project. Each example is small and fast (no simulation
runs): configs go through `taichi-mpm validate` (or its load_config + build_scene path), studies through
`taichi-mpm study --dry-run`, command lines point at missing or invalid files.

Runs are derandomized (the same examples every run) and count their examples; together they check more than
10 000 generated configs under `pytest -m slow`, and the first sixteenth of them in the default run.
"""
import contextlib
import copy
import io
import math
import os
import random
import sys
import warnings
from pathlib import Path

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from taichi_mpm.cli import main  # (first: it keeps Taichi's banner off stdout)
from taichi_mpm import analytic
from taichi_mpm.tools import stability  # noqa: F401,I001 - imported (Taichi runs uname, opens /dev/null) unwatched
from taichi_mpm import scene as scene_mod
from taichi_mpm.config import ConfigError, load_config
from taichi_mpm.scene import build_scene, shape_bounds

N_DICT, N_YAML, N_ARGV, N_STUDY = 8000, 2000, 400, 300
# the default run checks a sixteenth of the examples (the same first ones: derandomized), `-m slow` all of them
SHARE = [pytest.param(16, id="sixteenth"), pytest.param(1, id="all", marks=pytest.mark.slow)]


def fuzz_settings(n):
    return settings(max_examples=n, deadline=None, derandomize=True, database=None, print_blob=True,
                    suppress_health_check=list(HealthCheck))


# ---------------------------------------------------------------- watching writes and process launches
class Watch:
    """An audit hook (installed once, active only inside `around`): records every write, delete or
    rename of a path outside `root`, and every process launch."""

    WRITE_FLAGS = os.O_WRONLY | os.O_RDWR | os.O_CREAT | os.O_TRUNC | os.O_APPEND
    PATH_EVENTS = {"os.mkdir", "os.remove", "os.rmdir", "os.rename", "os.replace", "shutil.rmtree", "os.symlink",
                   "os.link", "os.truncate", "os.chmod", "os.chown", "shutil.copyfile", "shutil.move"}
    LAUNCH_EVENTS = {"subprocess.Popen", "os.system", "os.exec", "os.posix_spawn", "os.spawn", "os.fork",
                     "os.startfile", "pty.spawn"}

    def __init__(self):
        self.root, self.outside, self.launched = None, [], []
        sys.addaudithook(self._hook)

    def _inside(self, path) -> bool:
        if isinstance(path, int):
            return True   # an already open descriptor
        p = os.path.abspath(os.fsdecode(path))
        return p == self.root or p.startswith(self.root + os.sep) or p == os.devnull   # (Taichi's import)

    def _hook(self, event, args):
        if self.root is None:
            return
        if event == "open":
            path, mode, flags = args
            if path is not None and ((mode and any(c in mode for c in "wax+")) or (flags or 0) & self.WRITE_FLAGS) \
                    and not self._inside(path):
                self.outside.append((event, path))
        elif event in self.PATH_EVENTS:
            for path in args[:2]:
                if isinstance(path, (str, bytes, os.PathLike)) and not self._inside(path):
                    self.outside.append((event, path))
        elif event in self.LAUNCH_EVENTS:
            self.launched.append((event, args[:2]))

    @contextlib.contextmanager
    def around(self, root):
        self.root, self.outside, self.launched = os.path.abspath(root), [], []
        try:
            yield self
        finally:
            self.root = None


WATCH = Watch()


def run_cli(argv, root):
    """main(argv) with stdout/stderr captured and writes outside `root` recorded: (code, out, err)."""
    out, err = io.StringIO(), io.StringIO()
    with WATCH.around(root), contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(argv)
    assert not WATCH.outside, f"wrote outside {root}: {WATCH.outside}"
    assert not WATCH.launched, f"launched a process: {WATCH.launched}"
    return code, out.getvalue(), err.getvalue()


def check_exit(code, err):
    assert "Traceback" not in err, err
    assert code in (0, 2), (code, err)
    if code == 2:
        assert err.count("taichi-mpm: error:") == 1, err


# ---------------------------------------------------------------- scene size guard (a stand-in)
MAX_LATTICE = 4000


def _lattice_estimate(cfg) -> float:
    """Lattice points the scene builder would visit (over each body's bounding box)."""
    total = 0.0
    for b in cfg.bodies:
        if b.shape.type == "mesh":
            continue   # needs its file: the generated ones never exist
        lo, hi = shape_bounds(b.shape, cfg.dim, None)
        h = cfg.domain.dx / b.particles_per_cell
        total += math.prod(max(1.0, float(u - l) / h + 2) for l, u in zip(lo, hi))
    return total


def _too_big(cfg) -> bool:
    try:
        return not _lattice_estimate(cfg) <= MAX_LATTICE   # (also true for an infinite estimate)
    except OverflowError:
        return True


def guarded_build_scene(cfg, *a, **k):
    """build_scene, refusing scenes too big for a fast example. The generated valid configs are small; a
    mutation (particles_per_cell: 10^9, dx: 1e-9) can make a valid but huge scene whose building would take
    minutes. Until an up-front resource estimate refuses such sizes in the project itself, this guard stands
    in for it (as the ConfigError that estimate will raise)."""
    if _too_big(cfg):
        raise ConfigError("scene too large for a fuzz example (stand-in for the resource estimate)",
                          key="bodies.0.particles_per_cell")
    return build_scene(cfg, *a, **k)


@pytest.fixture
def guarded(monkeypatch):
    monkeypatch.setattr(scene_mod, "build_scene", guarded_build_scene)


# ---------------------------------------------------------------- strategies: valid small configs
# A valid config is drawn as its dimension, cell size, text fields and one integer that seeds the choice of
# every other option (a Hypothesis draw costs ~50 us; a config has ~80 choices): the examples stay cheap and
# reproducible, and shrinking the seed towards 0 still simplifies a failing config. Mutations (below) are drawn
# choice by choice.
# characters for generated text: letters, digits, YAML and path syntax, control characters, non-ASCII
# (a fixed alphabet: Hypothesis' full-Unicode tables take seconds to build)
CHARS = st.sampled_from(list("aZ0_-. /\\:#&*!|>%@`'\"{}[],?~=+\x00\x01\x07\t\n\r\x1b\x7f\x85\xa0éß中😀\u202e\u2028\ufeff"))
TEXT = st.text(CHARS, max_size=8)
NAMES = st.one_of(st.sampled_from(["test", "block", "a-b_c.d", "é", "x" * 40]), st.text(CHARS, min_size=1, max_size=8))


def _maybe(rng, d: dict, key, values, p=0.5):
    if rng.random() < p:
        d[key] = rng.choice(values)


def _material(rng) -> dict:
    if rng.random() < 0.25:
        m = dict(model="fluid", density=1000.0, K=rng.choice([1e3, 2e6]))
        _maybe(rng, m, "viscosity", [0.0, 1e-3])
        return m
    m = dict(model=rng.choice(["linear_elastic", "neo_hookean", "fixed_corotated"]), density=rng.choice([1.0, 1000.0]),
             E=rng.choice([1e3, 1e6, 2e11]))
    _maybe(rng, m, "nu", [0.0, 0.3, 0.49])
    if rng.random() < 0.3:
        m.update(tensile_strength=1e5, fracture_energy=10.0)
    return m


def _body(rng, dim, dx, lower, cells, materials, name) -> dict:
    """A body inside the domain: a box on cell boundaries, or a sphere/ring/cylinder that fits."""
    kind = rng.choice(["box", "sphere", "ring", "cylinder"][:{1: 2, 2: 3, 3: 4}[dim]])
    lo_i = [rng.randint(0, n - 1) for n in cells]
    hi_i = [rng.randint(l + 1, n) for l, n in zip(lo_i, cells)]
    blo = [o + i * dx for o, i in zip(lower, lo_i)]
    bhi = [o + i * dx for o, i in zip(lower, hi_i)]
    center = [(a + b) / 2 for a, b in zip(blo, bhi)]
    half = min(b - a for a, b in zip(blo, bhi)) / 2
    shape = {"box": dict(type="box", lower=blo, upper=bhi),
             "sphere": dict(type="sphere", center=center, radius=half),
             "ring": dict(type="ring", center=center, inner_radius=half / 2, outer_radius=half),
             "cylinder": dict(type="cylinder", center=center, radius=half / 2, height=half,
                              axis=rng.choice("xyz"))}[kind]
    body = dict(shape=shape, material=rng.choice(materials), particles_per_cell=rng.randint(1, 3))
    _maybe(rng, body, "placement", ["regular", "jittered"])
    _maybe(rng, body, "interface", [True, False], 0.3)
    if rng.random() < 0.5:
        body["name"] = name
    small = [-1.5, -0.2, 0.0, 0.3, 1.0]
    exprs = ["0.1 * sin(pi * x)", "x - 2 * x", "min(x, 1) if x > 0 else 0", "exp(-x**2)"]
    if rng.random() < 0.4:
        body["velocity"] = [rng.choice(small + exprs) for _ in range(dim)]
    if rng.random() < 0.15:  # initial stress: Voigt list
        body["stress"] = [rng.choice([0.0, -1e3, "-1e3 * x"]) for _ in range({1: 1, 2: 3, 3: 6}[dim])]
    region = dict(type="box", lower=blo, upper=bhi)
    if rng.random() < 0.2:
        load = dict(region=region) if rng.random() < 0.5 else {}
        if rng.random() < 0.5:
            load["pressure"] = rng.choice([0.0, 1e3])
        else:
            load["traction"] = [rng.choice(small) for _ in range(dim)]
        _maybe(rng, load, "ramp", [1.0, "min(t / 0.01, 1)", "sin(2 * pi * t)"])
        body["tractions"] = [load]
    if rng.random() < 0.15:
        body["prescribed_velocity"] = [dict(region=region, velocity=[rng.choice([0.0, "0.1 * t", None])
                                                                     for _ in range(dim - 1)] + [0.1])]
    if dim > 1 and rng.random() < 0.3:
        body["angular_velocity"] = rng.choice(small) if dim == 2 else [rng.choice(small) for _ in range(3)]
    if rng.random() < 0.2:
        body["damage_regions"] = [dict(shape=dict(type="box", lower=blo, upper=center if kind == "box" else bhi),
                                       value=rng.choice([0.5, 1.0]))]
    return body


def config_from(dim, dx, seed, name, body_name) -> dict:
    """The small valid config of this seed: up to 6 cells per axis in 3D (8 in 1D/2D), one or two bodies, and
    each optional section or key present or not."""
    rng = random.Random(seed)
    cells = [rng.randint(2, 6 if dim == 3 else 8) for _ in range(dim)]
    lower = [rng.randint(-2, 2) * dx for _ in range(dim)]
    upper = [l + n * dx for l, n in zip(lower, cells)]
    mats = {n: _material(rng) for n in rng.sample(["m", "steel", "water", "soft", "b2"], rng.randint(1, 2))}
    bodies = [_body(rng, dim, dx, lower, cells, list(mats), body_name) for _ in range(rng.randint(1, 2))]
    if len(bodies) == 2 and rng.random() < 0.7:  # placed at random, the second body often overlaps the first
        bodies[1]["overlap"] = rng.choice(["skip", "allow"])
    solver = dict(end_time=rng.choice([0.01, 0.5, 2.0]))
    for key, values in [("basis", ["linear", "gimp", "quadratic", "cubic"]), ("transfer", ["pic", "flip", "apic"]),
                        ("update", ["usl", "musl"]), ("cfl", [0.1, 0.4, 1.0]), ("dt", [1e-4, None]),
                        ("max_steps", [1, 100]), ("unroll", ["auto", True, False]), ("flip_blend", [0.0, 0.99, 1.0]),
                        ("gimp_domain", ["uniform", "deforming"]), ("energy_growth_limit", [0.5, None])]:
        _maybe(rng, solver, key, values, 0.3)
    if rng.random() < 0.3:
        solver["gravity"] = [rng.choice([0.0, -9.81, 1.0]) for _ in range(dim)]
    walls = dict(default=rng.choice(WALLS))
    for face in [f"{a}_{s}" for a in "xyz"[:dim] for s in ("min", "max")]:
        _maybe(rng, walls, face, WALLS, 0.2)
        if rng.random() < 0.05:  # a moving wall
            walls[face] = dict(type="velocity", velocity=[rng.choice([0.0, "0.5 * min(t / 0.1, 1)", None])
                                                          for _ in range(dim)])
    cfg = dict(name=name, dim=dim, domain=dict(lower=lower, upper=upper, dx=dx, boundaries=walls),
               solver=solver, materials=mats, bodies=bodies)
    _maybe(rng, cfg, "precision", ["f32", "f64"])
    # an explicit GPU arch is valid only where it exists (validate refuses it elsewhere, as run does); arch
    # names reach validation through the mutations and the --arch flag below
    _maybe(rng, cfg, "arch", ["auto", "cpu"])
    _maybe(rng, cfg["domain"], "sparse", [True, False], 0.3)
    if rng.random() < 0.3:
        for b in bodies:  # grips and velocity walls are not available with the crack finder
            b.pop("prescribed_velocity", None)
        for face, w in list(walls.items()):
            if isinstance(w, dict):
                walls[face] = "slip"
        cfg["crack"] = {}
        _maybe(rng, cfg["crack"], "kernel_radius", [1.5, 2.0])
        _maybe(rng, cfg["crack"], "contact_in_compression", [True, False])
    if rng.random() < 0.3:
        out = cfg["output"] = {}
        _maybe(rng, out, "dir", ["runs/{name}", "out"])
        _maybe(rng, out, "every", [0.01, 0.1])
        if rng.random() < 0.5:
            out["formats"] = rng.sample(["vtu", "npz", "png", "mp4", "gif"], rng.randint(0, 3))
        if rng.random() < 0.5:
            out["fields"] = rng.sample(["velocity", "stress", "J", "damage", "mass"], rng.randint(0, 3))
        if rng.random() < 0.5:
            out["render"] = dict(color_by=rng.choice(["speed", "von_mises"]), size=[64, 48], clim=[0.0, 1.0],
                                 camera=rng.choice(["iso", "xy"]))
    return cfg


WALLS = ["slip", "roller", "sticky", "free"]
# a run's name names its folder runs/NAME, so a valid one is a plain folder name (config.plain_name); names that
# are not reach it through the mutations below and tests/test_run_folder.py
RUN_NAMES = st.one_of(st.sampled_from(["test", "a-b_c.d", "é", "x" * 40]),
                      st.text(st.sampled_from([c for c in CHARS.elements if c.isprintable() and c not in "/\\"]),
                              min_size=1, max_size=8).map(lambda t: "n" + t.strip()))
valid_configs = st.builds(config_from, st.sampled_from([1, 2, 3]), st.sampled_from([0.5, 0.25, 0.2, 0.125, 0.1]),
                          st.integers(0, 2**32), RUN_NAMES, NAMES)


# ---------------------------------------------------------------- strategies: mutations
SCALARS = st.one_of(
    st.none(), st.booleans(), st.integers(-3, 3), st.integers(-(10**30), 10**30),
    st.sampled_from([0, -1, 2**63, 10**400]), st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0.0, -0.0, -1.0, 1e-300, 1e300, 5e-324, float("nan"), float("inf"), -float("inf")]),
    TEXT,
    st.sampled_from(["", "\x00", "\n", "\t", "\x1b[2J", "..", "../../x", "/", "\u202e", "é", "1e3", "0x10", "nan",
                     ".inf", "true", "null", "~", "box", "mesh", "fluid", "cubic", "{name}", "a" * 300]))


def _nest(n):
    v = 1.0
    for i in range(n):
        v = [v] if i % 2 else {"a": v}
    return v


WEIRD = st.one_of(   # anything a YAML file can hold: scalars, lists of the wrong length, mappings, deep nesting
    SCALARS, st.lists(SCALARS, max_size=5), st.lists(st.floats(-1, 1), max_size=5),
    st.dictionaries(st.one_of(TEXT, st.integers(-2, 2)), SCALARS, max_size=3),
    st.integers(1, 60).map(_nest),
    st.recursive(SCALARS, lambda kids: st.lists(kids, max_size=3) | st.dictionaries(TEXT, kids, max_size=3),
                 max_leaves=6))
NEW_KEYS = st.one_of(TEXT, st.sampled_from(["type", "shape", "dx", "E", "bodies", "1"]),
                     st.integers(-1, 3), st.booleans(), st.none())
MUTATIONS = st.sampled_from(["replace", "replace", "replace", "delete", "add_key", "resize", "bool"])


def _paths(node, prefix=()):
    """Every (container path, key) in a nested dict/list."""
    out = []
    if isinstance(node, dict):
        for k, v in node.items():
            out.append((prefix, k))
            out += _paths(v, prefix + (k,))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            out.append((prefix, i))
            out += _paths(v, prefix + (i,))
    return out


def _at(node, path):
    for p in path:
        node = node[p]
    return node


def mutate(draw, data, n):
    """Up to n mutations of a nested document: a value replaced (wrong type, NaN, huge, text, bool, deep), a key
    deleted or added, a list lengthened or shortened."""
    for _ in range(n):
        paths = _paths(data)
        if not paths:
            break
        where, key = paths[draw(st.integers(0, len(paths) - 1))]
        parent = _at(data, where)
        op = draw(MUTATIONS)
        if op == "replace":
            parent[key] = draw(WEIRD)
        elif op == "delete":
            del parent[key]
        elif op == "add_key":
            target = parent[key] if isinstance(parent[key], dict) else parent if isinstance(parent, dict) else data
            target[draw(NEW_KEYS)] = draw(WEIRD)
        elif op == "resize":
            value = parent[key]
            if isinstance(value, list) and value and draw(st.booleans()):
                value.pop()
            elif isinstance(value, list):
                value.append(draw(st.one_of(SCALARS, st.just(value[0] if value else 0.5))))
            else:
                parent[key] = [value] * draw(st.integers(0, 4))
        else:
            parent[key] = draw(st.booleans()) if not isinstance(parent[key], bool) else draw(st.integers(0, 1))
    return data


@st.composite
def mutated_configs(draw):
    """A valid config with one to three mutations; now and then the whole document replaced."""
    cfg = mutate(draw, draw(valid_configs), draw(st.integers(1, 3)))
    if draw(st.integers(0, 19)) == 0:
        cfg = draw(WEIRD)
    return cfg


configs = st.one_of(valid_configs, mutated_configs(), mutated_configs())


# ---------------------------------------------------------------- configs as dicts: load_config + build_scene
def validate_dict(data) -> int:
    """The path `taichi-mpm validate` takes, for a dict: 0 valid, 2 ConfigError; anything else escapes."""
    try:
        cfg = load_config(data)
        guarded_build_scene(cfg)
        return 0
    except ConfigError as e:
        if isinstance(data, dict):   # a config's error names its key (or says which empty key)
            assert e.key or "''" in str(e), str(e)
        return 2


@pytest.mark.parametrize("share", SHARE)
def test_generated_config_dicts(tmp_path, monkeypatch, share):
    monkeypatch.chdir(tmp_path)
    seen = {0: 0, 2: 0}

    n = N_DICT // share

    @fuzz_settings(n)
    @given(configs)
    def check(data):
        with WATCH.around(tmp_path):
            code = validate_dict(data)
        assert not WATCH.outside and not WATCH.launched
        seen[code] += 1

    check()
    print(f"config dicts: {seen[0]} valid, {seen[2]} refused")
    assert seen[0] + seen[2] >= n and seen[0] > n // 40 and seen[2] > n // 3, seen   # damage makes most invalid   # both kinds, well mixed


# ---------------------------------------------------------------- configs as YAML files: the CLI in-process
DAMAGE = st.sampled_from(["cut", "insert", "tab", "dup", "alias", "bytes"])
INSERTS = st.sampled_from([":", "- ", "{", "]", "&a ", "*a", "!!python/object/apply:os.system ['echo hi']", "\x00",
                           "\t", "? ", "%YAML 1.1\n", "---\n", "'", '"', "\\", "\u0085", "\ufeff", "#", "<<: *a\n"])
# aliases that expand to 9^8 = 43 million values if walked naively
ALIAS_BOMB = "l0: &l0 [x]\n" + "".join(f"l{i}: &l{i} [" + ", ".join([f"*l{i - 1}"] * 9) + "]\n" for i in range(1, 9))


@st.composite
def damaged_yaml(draw, dumped):
    text = draw(dumped)
    op = draw(DAMAGE)
    pos = draw(st.integers(0, len(text)))
    if op == "cut":   # small draws are the common ones: cut near the end
        return text[:len(text) - pos]
    if op == "insert":
        return text[:pos] + draw(INSERTS) + text[pos:]
    if op == "tab":
        return text.replace("  ", "\t", 1)
    if op == "dup":   # a duplicated line: often a duplicate key
        lines = text.splitlines(keepends=True)
        return text + lines[draw(st.integers(0, len(lines) - 1))]
    if op == "alias":
        return ALIAS_BOMB + text.replace("bodies:", "bodies: *l8\nx_bodies:", 1)
    return None   # raw bytes (invalid UTF-8)


OVERRIDE_KEYS = st.one_of(st.sampled_from(
    ["solver.basis", "domain.dx", "dim", "name", "bodies.0.velocity", "bodies.1.shape.radius", "bodies.-1.material",
     "bodies.x.y", "bodies.0.shape.type.x", "materials.m.E", "output.dir", "a..b", ".x", "x.", "solver", "bodies",
     "bodies.99", "bodies.1_0", "bodies. 0", "domain.lower.0.x"]), TEXT)
OVERRIDE_VALUES = st.one_of(st.sampled_from(["cubic", "0.01", "[0, 1]", "[", "{a: 1}", "null", "true", "1e400", ".nan",
                                             "-1", "", "&a [*a]", "!!python/name:os.system", "'x", "10000000000"]), TEXT)
OVERRIDES = st.builds(lambda k, sep, v: f"{k}{sep}{v}", OVERRIDE_KEYS, st.sampled_from(["=", "=", ":", ""]),
                      OVERRIDE_VALUES)


def yaml_texts():
    """YAML documents: generated configs dumped, and texts damaged after dumping."""
    dumped = configs.map(lambda d: yaml.safe_dump(d, sort_keys=False, allow_unicode=True, default_flow_style=None))
    return st.one_of(dumped, dumped, damaged_yaml(dumped))


@pytest.mark.parametrize("share", SHARE)
def test_generated_config_files_through_the_cli(tmp_path, monkeypatch, guarded, share):
    monkeypatch.chdir(tmp_path)
    path = tmp_path / "config.yaml"
    seen = {0: 0, 2: 0}

    n = N_YAML // share

    @fuzz_settings(n)
    @given(yaml_texts(), st.binary(max_size=12), st.lists(OVERRIDES, max_size=2))
    def check(text, raw, overrides):
        if text is None:
            path.write_bytes(b"name: x\n" + raw + b"\xff\xfe")
        else:
            path.write_text(text, encoding="utf-8")
        code, out, err = run_cli(["validate", str(path), *(f"--set={o}" for o in overrides)], tmp_path)
        check_exit(code, err)
        if code == 0:
            assert "valid:" in err and yaml.safe_load(out)["name"]
        seen[code] += 1

    check()
    print(f"config files: {seen[0]} valid, {seen[2]} refused")
    assert seen[0] + seen[2] >= n and seen[0] > n // 40 and seen[2] > n // 3, seen   # damage makes most invalid


def test_at_least_ten_thousand_configs():
    assert N_DICT + N_YAML >= 10_000


# ---------------------------------------------------------------- command lines
FLAGS = {
    "run": ["--set", "--out", "--quiet", "--resume", "--arch"],
    "validate": ["--set", "--arch"],
    "demo": ["--list", "--set", "--out", "--quiet", "--resume", "--arch"],
    "render": ["--color-by", "--size", "--camera", "--movie"],
    "compare": ["--vary", "--set", "--out", "--overwrite", "--color-by", "--size", "--camera", "--no-movie", "--arch",
                "--quiet"],
    "gui": ["--set", "--arch", "--max-frames", "--screenshot"],
    "study": ["--jobs", "--scheduler", "--out", "--resume", "--overwrite", "--allow-problem", "--dry-run"],
}
arg_text = st.one_of(st.text(CHARS, max_size=12), st.sampled_from(
    ["", "-", "--", "-x", "=", "solver.basis=cubic", "bodies.0.velocity=[1,2]", "a..b=1", "bodies.-1.x=2", "x=",
     "=1", "a.b.c.d.e=[[[1]]]", "cuda", "0", "-3", "10x", "9999999999x1", "nan", "os:system", "\x00", "é", "{"]))


@st.composite
def command_lines(draw):
    """A subcommand, its positional pointing at a missing, empty, invalid or not-a-file input, random options."""
    cmd = draw(st.sampled_from(list(FLAGS) + ["bogus", "--version", "--help", "-h"]))
    argv = [cmd]
    if cmd in FLAGS and (cmd != "demo" or draw(st.booleans())):
        target = draw(st.sampled_from(["missing.yaml", "empty.yaml", "list.yaml", "bad.yaml", "folder", "bad_study.yaml",
                                       "no_such_demo", "\x00", ""]))
        argv.append(target)
    for _ in range(draw(st.integers(0, 4))):
        flag = draw(st.sampled_from(FLAGS.get(cmd, ["--set"]) + ["--bogus", "-q", "--help"]))
        argv.append(flag)
        if draw(st.integers(0, 3)):
            argv.append(draw(arg_text))
    if draw(st.integers(0, 5)) == 0:
        argv.insert(draw(st.integers(0, len(argv))), draw(arg_text))
    return argv


def test_command_lines(tmp_path, monkeypatch, guarded):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "empty.yaml").write_text("")
    (tmp_path / "list.yaml").write_text("- 1\n- 2\n")
    (tmp_path / "bad.yaml").write_text("name: x\ndim: 2\ndomain: {lower: [0, 0], upper: [1, 1], dx: 0.3}\n")
    (tmp_path / "bad_study.yaml").write_text("study: ..\nproblem: {type: os:system}\nvary: {domain.dx: [0.1]}\n")
    (tmp_path / "folder").mkdir()
    before = sorted(p.name for p in tmp_path.rglob("*"))
    seen = {0: 0, 2: 0}

    @fuzz_settings(N_ARGV)
    @given(command_lines())
    def check(argv):
        code, out, err = run_cli(argv, tmp_path)
        check_exit(code, err)
        seen[code] += 1

    check()
    print(f"command lines: {seen[0]} exit 0, {seen[2]} exit 2")
    assert sum(seen.values()) >= N_ARGV and seen[2] > N_ARGV // 2, seen
    assert sorted(p.name for p in tmp_path.rglob("*")) == before   # an invalid command writes nothing


# ---------------------------------------------------------------- study files
EVIL = """import pathlib
pathlib.Path(__file__).with_name("IMPORTED").write_text("")
def make(spec):
    pathlib.Path(__file__).with_name("CALLED").write_text("")
"""
MMS = {"type": "mms_axis_aligned", "dim": 1, "amplitude": 0.001}
VALID_STUDIES = [   # small valid studies (each case is validated by building its config: keep them few)
    dict(study="bases", problem=MMS, vary={"solver.basis": ["linear", "cubic"], "domain.dx": [0.0625, 0.03125]},
         metric="error_rms", samples=3),
    dict(study="impact", problem={"type": "impact", "mach": 0.1, "cells": 8}, energy_limit=1.1, timeout=60,
         cases=[{"problem.E": 1.0e5}, {"solver.cfl": 0.8}, {"problem.type": "compression", "problem.J": 0.5}]),
    dict(study="disks", problem={"type": "colliding_disks", "cells": 10}, metric="error_energy", repeats=2, jobs=2,
         vary={"solver.transfer": ["pic", "apic"]}, time_metric="wall_time"),
    dict(study="bar.1", problem={"type": "vibrating_bar", "cells": 8}, set={"arch": "cpu"}, convergence_key="domain.dx",
         description="a bar", vary={"problem.v0": [0.1, 0.2], "precision": ["f32"]}),
    dict(study="base-cfg", base="block.yaml", vary={"solver.transfer": ["pic", "flip"]}, metric="energy_drift"),
    # the new areas through a study: knots, a plastic material, a grip, probes observed (issue 30)
    dict(study="areas", base="areas.yaml", vary={"solver.transfer": ["pic", "apic"],
                                                 "materials.m.yield_stress": [1e3, 1e4]}, observe="p.vy@max"),
]
AREAS_BASE = dict(name="areas", dim=2, arch="cpu", domain=dict(lower=[0, 0], upper=[1, 1], dx=0.25,
                                                                knots=dict(x=[0, 0, 0, 0, 0.5, 1, 1, 1, 1])),
                  solver=dict(basis="cubic", end_time=0.01),
                  materials=dict(m=dict(model="von_mises", density=1000.0, E=1e4, yield_stress=1e3)),
                  bodies=[dict(shape=dict(type="box", lower=[0.25, 0.25], upper=[0.75, 0.75]), material="m",
                               prescribed_velocity=[dict(region=dict(type="box", lower=[0.25, 0.25],
                                                                     upper=[0.75, 0.4]), velocity=[None, 0.0])])],
                  output=dict(probes=[dict(name="p", type="point", point=[0.5, 0.7]), dict(name="g", type="grip", grip=0)]))
STUDY_NAMES = st.one_of(st.sampled_from(["..", ".", "a/b", "a\\b", "", "x" * 120, ".hidden", "a\x00b"]), NAMES, SCALARS)
# problem types that are not the project's: must never be imported or called (the factory in EVIL writes a file)
FOREIGN = st.sampled_from(["os:system", "subprocess:run", "builtins:exec", "builtins:eval", "evil_fuzz_problem:make",
                           "shutil:rmtree", "taichi_mpm.cli:main", "importlib:import_module", ":", "a:b:c", "os:",
                           "study_problems:mms1d"])
FOREIGN_AT = st.sampled_from(["problem", "cases", "vary"])


@st.composite
def study_files(draw):
    """A valid small study, mutated zero to two times; often with a foreign problem type somewhere or a bad name."""
    data = copy.deepcopy(draw(st.sampled_from(VALID_STUDIES)))
    if draw(st.integers(0, 2)) == 0:
        where, kind = draw(FOREIGN_AT), draw(FOREIGN)
        if where == "problem" or "base" in data:
            data.pop("base", None)
            data["problem"] = {"type": kind}
        elif where == "cases":
            data["cases"] = [*data.get("cases", []), {"problem.type": kind}]
        else:
            data.setdefault("vary", {})["problem.type"] = [data["problem"]["type"], kind]
    if draw(st.integers(0, 4)) == 0:
        data["study"] = draw(STUDY_NAMES)
    return mutate(draw, data, draw(st.integers(0, 2)))


def test_study_files_dry_run(tmp_path, monkeypatch):
    (tmp_path / "evil_fuzz_problem.py").write_text(EVIL)
    from conftest import make_cfg
    (tmp_path / "block.yaml").write_text(yaml.safe_dump(make_cfg(2, dx=0.25)))
    (tmp_path / "areas.yaml").write_text(yaml.safe_dump(AREAS_BASE))
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.chdir(tmp_path)
    path = tmp_path / "study.yaml"
    path.write_text("")
    before = sorted(p.name for p in tmp_path.rglob("*"))
    seen = {0: 0, 2: 0}

    @fuzz_settings(N_STUDY)
    @given(study_files(), st.booleans())
    def check(data, as_flow):
        path.write_text(yaml.safe_dump(data, sort_keys=False, allow_unicode=True,
                                       default_flow_style=None if as_flow else False))
        code, out, err = run_cli(["study", str(path), "--dry-run"], tmp_path)
        check_exit(code, err)
        seen[code] += 1
        assert "evil_fuzz_problem" not in sys.modules
        assert not (tmp_path / "IMPORTED").exists() and not (tmp_path / "CALLED").exists()

    check()
    print(f"study files: {seen[0]} valid, {seen[2]} refused")
    assert sum(seen.values()) >= N_STUDY and seen[0] > 10 and seen[2] > N_STUDY // 2, seen
    assert sorted(p.name for p in tmp_path.rglob("*")) == before   # a dry run writes nothing


# ---------------------------------------------------------------- the new config areas (issue 30)
# Knots, mapped grids, plasticity, loads, grips, expressions and probes (observe): a small valid 2D/3D scene with
# one area filled in from a seed, then zero to three mutations inside that area's subtree (where the area's own
# checks must catch them); advise command lines with observe/tolerance/reference specs. Derandomized, fast
# (a few hundred examples each; no simulation runs: advise is stopped where its sweep would start).
N_AREA, N_AREA_CLI, N_ADVISE = 400, 120, 120
AREAS = ("knots", "map", "plasticity", "loads", "grips", "expressions", "observe")
EXPR_TOKENS = ["x", "y", "z", "t", "pi", "e", "1", "0.5", "1e30", "1e-30", "1e308", "-", "+", "*", "/", "**", "%",
               "(", ")", "sin(", "exp(", "log(", "sqrt(", "min(", "max(", "clip(", "step(", ",", " if ", " else ",
               " and ", " not ", "<", "==", "__import__", "os", ".", "[", "]", "lambda", ":", "'", "9" * 40, "**64",
               "**65", "open(", "x**x**x"]


def _expression_text(rng) -> str:
    if rng.random() < 0.5:   # well-formed
        return rng.choice(["0.1 * sin(pi * x)", "min(t / 0.01, 1)", "exp(-x**2) * 1e3", "x if x > 0.5 else -x",
                           "clip(t, 0, 1) * 2", "1e30 * x", "log(x)", "sqrt(-1 - t)", "1 / (t - 0.005)",
                           "exp(1e3 * t)", "x ** 64", "step(x - 0.5)"])
    return "".join(rng.choice(EXPR_TOKENS) for _ in range(rng.randint(1, 8)))


def area_config(area, seed) -> tuple[dict, tuple]:
    """A small valid scene with `area` filled in, and the path of the area's subtree (for the mutations)."""
    rng = random.Random(seed)
    dim = 2 if area == "map" else rng.choice([2, 2, 3])
    dx, n = 0.125, 8
    body_lo, body_hi = [0.25] * dim, [0.625] * dim
    mat = dict(model="neo_hookean", density=1000.0, E=rng.choice([1e4, 1e6]))
    body = dict(shape=dict(type="box", lower=body_lo, upper=body_hi), material="m", particles_per_cell=2)
    cfg = dict(name="area", dim=dim, precision=rng.choice(["f32", "f64"]), arch="cpu",
               domain=dict(lower=[0.0] * dim, upper=[n * dx] * dim, dx=dx), materials=dict(m=mat), bodies=[body],
               solver=dict(end_time=rng.choice([0.01, 0.1])))
    region = dict(type="box", lower=body_lo, upper=[0.4] * dim)
    path: tuple = ()
    if area == "knots":
        basis = rng.choice(["linear", "quadratic", "cubic"])
        p = {"linear": 1, "quadratic": 2, "cubic": 3}[basis]
        cfg["solver"]["basis"] = basis
        inner = sorted(rng.choice([0.25, 0.5, 0.5, 0.75, 0.5 + 1e-9]) for _ in range(rng.randint(0, 3)))
        cfg["domain"]["knots"] = {"xyz"[rng.randrange(dim)]: [0.0] * (p + 1) + inner + [1.0] * (p + 1)}
        path = ("domain", "knots")
    elif area == "map":
        if rng.random() < 0.5:
            angle = rng.choice([90.0, 180.0, 360.0])
            pieces = max(1, math.ceil(angle / 90 - 1e-9))
            cfg["domain"].update(lower=[-1.125, -1.125], upper=[1.125, 1.125])
            cfg["domain"]["map"] = dict(type="annulus", inner_radius=0.5, outer_radius=1.0, angle=angle,
                                        cells=[pieces * rng.randint(1, 4), rng.randint(1, 4)])
            body["shape"] = dict(type="sphere", center=[0.52, 0.52], radius=0.1)
        else:
            net = [[[0.05 + 0.45 * i, 0.05 + 0.45 * j] for j in range(3)] for i in range(3)]
            cfg["domain"]["map"] = dict(type="nurbs", knots=dict(x=[0, 0, 0, 1, 1, 1], y=[0, 0, 0, 1, 1, 1]),
                                        control_points=net, refine=[rng.randint(1, 6), rng.randint(1, 6)])
        path = ("domain", "map")
    elif area == "plasticity":
        model = rng.choice(["von_mises", "drucker_prager", "snow"])
        cfg["materials"]["m"] = {"von_mises": dict(model="von_mises", density=1000.0, E=1e6, yield_stress=1e4,
                                                   hardening=rng.choice([0.0, 1e5])),
                                 "drucker_prager": dict(model="drucker_prager", density=1600.0, E=1e6,
                                                        friction_angle=30.0, cohesion=rng.choice([0.0, 1e3]),
                                                        dilatancy=rng.choice([0.0, 10.0]),
                                                        fit=rng.choice(["compression", "plane_strain", "simple_shear"])),
                                 "snow": dict(model="snow", density=400.0, E=1.4e5, hardening=10.0,
                                              max_hardening=rng.choice([1.0, 10.0, 1e3]))}[model]
        path = ("materials", "m")
    elif area == "loads":
        body["tractions"] = [dict(region=region, pressure=rng.choice([1e2, -1e3]), ramp=_expression_text(rng)),
                             dict(traction=[rng.choice([0.0, 1e3]) for _ in range(dim)], faces=["y_max"])]
        path = ("bodies", 0, "tractions")
    elif area == "grips":
        body["prescribed_velocity"] = [dict(region=region, velocity=[None] * (dim - 1) + [rng.choice([0.0, "0.1 * t"])])]
        cfg["output"] = dict(probes=[dict(name="g", type="grip", grip=0)])
        path = ("bodies", 0, "prescribed_velocity")
    elif area == "expressions":
        body["velocity"] = [_expression_text(rng) for _ in range(dim)]
        body["stress"] = [_expression_text(rng) if rng.random() < 0.3 else 0.0 for _ in range({2: 3, 3: 6}[dim])]
        cfg["domain"]["boundaries"] = dict(default="slip", y_max=dict(type="velocity", velocity=[
            _expression_text(rng) if rng.random() < 0.5 else None for _ in range(dim)]))
        path = ("bodies", 0)
    else:   # observe: probes of every type
        cfg["output"] = dict(probes=[dict(name="p", type="point", point=[0.3] * dim), dict(name="b", type="body", body=0),
                                     dict(name="r", type="region", region=region), dict(name="w", type="wall", face="y_min"),
                                     dict(name="c", type="contact", body=0)][: rng.randint(1, 5)],
                             probe_every=rng.choice([None, "step", 0.001]))
        path = ("output",)
    return cfg, path


@st.composite
def area_configs(draw):
    area = draw(st.sampled_from(AREAS))
    cfg, path = area_config(area, draw(st.integers(0, 2**32)))
    n = draw(st.integers(0, 3))
    if n:   # inside the area's subtree (held in a mapping, so that it may be replaced or deleted whole)
        parent, key = _at(cfg, path[:-1]), path[-1]
        holder = {"area": parent[key]}
        mutate(draw, holder, n)
        if "area" in holder:
            parent[key] = holder["area"]
        else:
            del parent[key]
    return cfg


def test_new_config_areas_as_dicts(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    seen = {0: 0, 2: 0}

    @fuzz_settings(N_AREA)
    @given(area_configs())
    def check(data):
        with WATCH.around(tmp_path), warnings.catch_warnings():
            warnings.simplefilter("ignore")   # ConfigWarning / SizeWarning: said, and allowed
            code = validate_dict(data)
        assert not WATCH.outside and not WATCH.launched
        seen[code] += 1

    check()
    print(f"new areas (dicts): {seen[0]} valid, {seen[2]} refused")
    assert sum(seen.values()) >= N_AREA and seen[0] > N_AREA // 10 and seen[2] > N_AREA // 10, seen


def test_new_config_areas_through_the_cli(tmp_path, monkeypatch, guarded):
    monkeypatch.chdir(tmp_path)
    path = tmp_path / "config.yaml"
    seen = {0: 0, 2: 0}

    @fuzz_settings(N_AREA_CLI)
    @given(area_configs(), st.lists(OVERRIDES, max_size=1))
    def check(data, overrides):
        path.write_text(yaml.safe_dump(data, sort_keys=False, allow_unicode=True, default_flow_style=None))
        code, out, err = run_cli(["validate", str(path), *(f"--set={o}" for o in overrides)], tmp_path)
        check_exit(code, err)
        seen[code] += 1

    check()
    print(f"new areas (cli): {seen[0]} valid, {seen[2]} refused")
    assert sum(seen.values()) >= N_AREA_CLI and seen[0] > 5 and seen[2] > 5, seen


# each part is drawn from valid values two times in three, so that a fair share of lines passes every check
def _mostly(valid, invalid):
    return st.one_of(st.sampled_from(valid), st.sampled_from(valid), invalid)


OBSERVE = _mostly(["kinetic_energy", "kinetic_energy@max", "strain_energy@maxabs", "momentum_x@end"],
                  st.one_of(st.sampled_from(["p.x@end", "b.vy@mean", "error_rel", "os:system", "p.", "@max",
                                             "kinetic_energy@bogus", "mypkg.obs:tip", "", "\x00", "w.fy", "nope.col"]),
                            TEXT))
TOLERANCES = _mostly(["1%", "0.01", "5%"], st.sampled_from(["1e-30", "0", "-1", "nan", "inf", "abc", "100%", "1e400",
                                                            "", "5 %"]))
REFERENCES = _mostly([None, "finest", "richardson"], st.sampled_from(["exact", "0.5", "nan", "1e999", "bogus", "-0"]))


@st.composite
def advise_lines(draw):
    argv = ["advise"]
    if draw(st.integers(0, 5)):
        argv.append(draw(_mostly(["block.yaml", "probed.yaml"], st.sampled_from(["missing.yaml", "empty.yaml"]))))
    else:
        argv += ["--problem", draw(st.sampled_from(["vibrating_bar", "{type: impact, mach: 0.1}", "os:system", "{",
                                                    "{type: vibrating_bar, cells: 1e9}", "nope"]))]
    argv += ["--observe", draw(OBSERVE), "--tolerance", draw(TOLERANCES)]
    ref = draw(REFERENCES)
    if ref is not None:
        argv += ["--reference", ref]
    for flag, values in (("--bases", ["linear,cubic", "quadratic", "bogus", ""]), ("--transfers", ["apic", "pic,x"]),
                         ("--ppc", ["1,2", "0", "9", "a"]), ("--levels", ["2", "0", "9", "x"]),
                         ("--cost", ["work", "wall_time", "bogus"]), ("--set", ["domain.dx=0.125", "bogus", "dim=7"])):
        if draw(st.integers(0, 5)) == 0:
            argv += [flag, draw(st.sampled_from(values))]
    return argv


class _WouldRun(ConfigError):
    pass


def test_advise_command_lines(tmp_path, monkeypatch):
    """Everything advise checks before its sweep; a line that passes them is stopped where the sweep would
    write its folder (counted as valid): no case runs, nothing is written, no process starts."""
    from conftest import make_cfg
    from taichi_mpm.tools import advise as advise_mod

    def stop(*a, **k):
        raise _WouldRun("fuzz: the sweep would start here")

    monkeypatch.setattr(advise_mod, "prepare_out", stop)
    monkeypatch.chdir(tmp_path)
    (tmp_path / "block.yaml").write_text(yaml.safe_dump(make_cfg(2, dx=0.25)))
    probed = make_cfg(2, dx=0.25)
    probed["output"] = dict(probes=[dict(name="p", type="point", point=[0.4, 0.4]), dict(name="b", type="body", body=0)])
    (tmp_path / "probed.yaml").write_text(yaml.safe_dump(probed))
    (tmp_path / "empty.yaml").write_text("")
    before = sorted(p.name for p in tmp_path.rglob("*"))
    seen = {"would run": 0, 2: 0, 0: 0}

    @fuzz_settings(N_ADVISE)
    @given(advise_lines())
    def check(argv):
        code, out, err = run_cli(argv, tmp_path)
        check_exit(code, err)
        seen["would run" if "the sweep would start here" in err else code] += 1

    check()
    print(f"advise lines: {seen}")
    assert sum(seen.values()) >= N_ADVISE and seen["would run"] > 3 and seen[2] > N_ADVISE // 3, seen
    assert sorted(p.name for p in tmp_path.rglob("*")) == before
