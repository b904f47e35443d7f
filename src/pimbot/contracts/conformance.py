"""Plugins are checked for what their code does, not what it declares, each failure one line.

A plugin's attack or defense is checked when it registers (`check_hooked_class`): every
hook point it lists is overridden, every hook it overrides is listed, no method is a near
miss of a hook's name (`observe_` for `observe`: it would never run), and no field a
compiled program cannot trace (text, a bool, a tuple of text) is a pytree leaf. Its hooks'
outputs are checked where the rollout and the learners call them, while the program is
traced (`install_checks`, `OutputCheck`: shapes are static, so a check costs nothing when the
program runs and cannot change a number). An exception inside a plugin's code becomes one
line naming the plugin's file and line (`plugin_code`, `PluginCodeError`); its full
traceback stays on the error (`pimbot.plugins.full_traceback`).

Every failure is a `ContractError`, an `InvalidParameter`: the command line prints it as
one line and exits with status 2. This follows Gymnasium's `env_checker` and PettingZoo's
`parallel_api_test`, which call an environment's methods and check what comes back
(docs/extending.md, "The rules a plugin follows").
"""

from __future__ import annotations

import ast
import contextlib
import dataclasses
import difflib
import functools
import inspect
import re
import textwrap
import traceback
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Any

import jax
import numpy as np

from pimbot.errors import InvalidParameter

PACKAGE_DIR = Path(__file__).resolve().parents[1]
"""The pimbot package: code outside it is a plugin's (or a library's)."""


class ContractError(InvalidParameter):
    """A plugin that does not keep its contract; the message is one line, starting with the
    plugin's file and line where they are known."""

    located = True
    """The message says where (`pimbot.plugins.load` passes it on as it is)."""


class PluginCodeError(ContractError):
    """An exception raised inside a plugin's code, as one line; the exception itself is
    its `__cause__` (with its traceback)."""


def is_builtin(obj: Any) -> bool:
    """Whether `obj` (a class, a function, or an instance's class) is pimbot's own code."""
    module = getattr(obj, "__module__", None) or type(obj).__module__
    return module == "pimbot" or module.startswith("pimbot.")


def source_file(obj: Any) -> str | None:
    """The file `obj` (a class or function, unwrapped) is defined in, or None."""
    try:
        return inspect.getsourcefile(inspect.unwrap(obj))
    except (TypeError, OSError):
        return None


def location(obj: Any, line: int | None = None) -> str:
    """``FILE:LINE`` of a class or function (or of `line` in its file); its qualified name
    where there is no source file (defined in a REPL)."""
    obj = inspect.unwrap(obj)
    path = source_file(obj)
    if path is None:
        return getattr(obj, "__qualname__", repr(obj))
    if line is None:
        try:
            lines, line = inspect.getsourcelines(obj)
            # the `class`/`def` line itself, after any decorators
            line += next((i for i, text in enumerate(lines) if text.lstrip().startswith(_HEADS)), 0)
        except (OSError, TypeError):
            code = getattr(obj, "__code__", None)
            line = code.co_firstlineno if code is not None else None
    return f"{path}:{line}" if line else path


_HEADS = ("class ", "def ", "async def ")


def member_line(cls: type, name: str) -> int | None:
    """The line where class `cls` itself assigns or defines `name`, or None."""
    try:
        lines, start = inspect.getsourcelines(cls)
    except (OSError, TypeError):
        return None
    tree = ast.parse(textwrap.dedent("".join(lines)))
    body = next((n.body for n in ast.walk(tree) if isinstance(n, ast.ClassDef)), [])
    for node in body:
        targets = []
        if isinstance(node, ast.AnnAssign):
            targets = [node.target]
        elif isinstance(node, ast.Assign):
            targets = node.targets
        elif isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef) and node.name == name:
            return start + node.lineno - 1
        if any(isinstance(t, ast.Name) and t.id == name for t in targets):
            return start + node.lineno - 1
    return None


def member_location(cls: type, name: str) -> str:
    """``FILE:LINE`` of `name` in the class of the MRO that defines it (the class itself
    where none does)."""
    owner = next((k for k in cls.__mro__ if name in vars(k)), cls)
    return location(owner, member_line(owner, name))


# --- registration: hooks listed ⇔ overridden, no near-miss names, static text fields -----


OVERRIDABLE = ("init_state", "validate", "metrics")
"""Methods of `Attack` and `Defense` besides the hooks that a plugin overrides (their
near misses are refused too, and an exception inside them is one line)."""


def check_hooked_class(
    cls: type, base: type, hooks: tuple[str, ...], kind: str, optional: tuple[str, ...] = ()
) -> None:
    """Refuses a class of hook points whose code does not match what it declares.

    Args:
        cls: the attack or defense class being registered (a subclass of `base`).
        base: `Attack` or `Defense`: a hook is overridden where `cls`'s method is not the
            base's.
        hooks: every hook point of the contract.
        kind: "attack" or "defense", for the messages.
        optional: hook points `cls` overrides but does not require (`Attack.optional_hooks`:
            consulted where a learner has them).

    Raises:
        ContractError: the first mismatch, naming the file and line.
    """
    name = getattr(cls, "name", cls.__name__)
    what = f"{kind} {name}"
    listed = tuple(cls.hooks)
    for hook in (*listed, *optional):
        if hook not in hooks:
            guess = did_you_mean(hook, hooks)
            raise ContractError(
                f"{member_location(cls, 'hooks')}: {what}: unknown hook point {hook!r}{guess}; "
                f"the hook points are {', '.join(hooks)}"
            )
    overridden = [h for h in hooks if overrides(cls, base, h)]
    near = _near_misses(cls, base, hooks, overridden)
    for hook in listed:
        if hook not in overridden:
            found = [m for m, h in near if h == hook]
            hint = f"; its method {found[0]}() is misspelt: rename it {hook}" if found else ""
            raise ContractError(
                f"{member_location(cls, 'hooks')}: {what}: hooks lists {hook!r} but the class "
                f"does not override {hook}(){hint}"
            )
    for hook in overridden:
        if hook not in listed and hook not in optional:
            raise ContractError(
                f"{member_location(cls, hook)}: {what}: {hook}() overrides the hook point "
                f"{hook!r}, which hooks does not list: add it to hooks (a learner without that "
                f"hook point would run the plugin without it){_optional_hint(base)}"
            )
    for method, hook in near:
        raise ContractError(
            f"{member_location(cls, method)}: {what}: method {method}() is no hook point and "
            f"would never be called: did you mean {hook}()?"
        )
    check_static_fields(cls, what)


def _optional_hint(base: type) -> str:
    if not hasattr(base, "optional_hooks"):
        return ""
    return ", or to optional_hooks if it may run where a learner lacks it"


def overrides(cls: type, base: type, name: str) -> bool:
    """Whether `cls` has its own `name` rather than the base class's."""
    mine = inspect.unwrap(getattr(cls, name))
    return mine is not inspect.unwrap(getattr(base, name))


def did_you_mean(name: str, choices: Iterable[str]) -> str:
    close = difflib.get_close_matches(name, list(choices), n=1, cutoff=0.75)
    return f" (did you mean {close[0]!r}?)" if close else ""


def _near_misses(cls, base, hooks, overridden) -> list[tuple[str, str]]:
    """(method, hook) for every public method `cls` (below `base`) defines whose name is a
    near miss of a hook point it does not override (`observe_`, `emit2`, `Observe`)."""
    own = {
        method
        for klass in cls.__mro__
        if klass not in base.__mro__
        for method, value in vars(klass).items()
        if callable(value) and not method.startswith("_")
    }
    wanted = [h for h in hooks if h not in overridden]
    wanted += [m for m in OVERRIDABLE if hasattr(base, m) and not overrides(cls, base, m)]
    found = []
    for method in sorted(own - set(hooks) - set(dir(base))):
        squeezed = re.sub(r"[\W\d_]+", "", method).lower()
        exact = [h for h in wanted if h.replace("_", "") == squeezed]
        close = exact or difflib.get_close_matches(method, wanted, n=1, cutoff=0.85)
        if close:
            found.append((method, close[0]))
    return found


STATIC_ANNOTATION = re.compile(r"^(str|bool|Literal\[.*\]|tuple\[str\b.*\])(\s*\|\s*None)?$")
"""Annotations of fields a program cannot trace (text, flags, tuples of text)."""


def check_static_fields(cls: type, what: str) -> None:
    """Refuses a field of a `flax.struct` dataclass that is a pytree leaf (traced) but holds
    text, a bool or a tuple of text: it fails only when the program is compiled, with a
    traceback into JAX; it must be `struct.field(pytree_node=False)`."""
    if not dataclasses.is_dataclass(cls):
        return
    for field in dataclasses.fields(cls):
        if not field.metadata.get("pytree_node", True):
            continue
        default = field.default
        annotation = (
            field.type if isinstance(field.type, str) else getattr(field.type, "__name__", "")
        )
        text_tuple = (
            isinstance(default, tuple) and default and all(isinstance(v, str) for v in default)
        )
        if isinstance(default, str | bool) or text_tuple or STATIC_ANNOTATION.match(annotation):
            kind = annotation or type(default).__name__
            raise ContractError(
                f"{member_location(cls, field.name)}: {what}: field {field.name} ({kind}) is a "
                f"traced pytree leaf; mark it {field.name}: {kind} = "
                "struct.field(pytree_node=False, default=...) (text, bools and tuples of text "
                "are structure, not numbers)"
            )


# --- trace time: hook outputs against the contract ---------------------------------------


def aval(x: Any) -> tuple[tuple[int, ...], str] | None:
    """(shape, dtype name) of an array, tracer or Python number; None for anything else."""
    if isinstance(x, bool | int | float | complex) or hasattr(x, "shape"):
        dtype = x.dtype if hasattr(x, "dtype") else jax.numpy.result_type(x)
        return tuple(np.shape(x)), np.dtype(dtype).name if _is_numpy(dtype) else str(dtype)
    return None


def _is_numpy(dtype) -> bool:
    try:
        np.dtype(dtype)
    except TypeError:
        return False
    return True


def describe(x: Any) -> str:
    """`float32[5, 2]`, `int32[]`, or the type of a value that is no array."""
    found = aval(x)
    if found is None:
        return type(x).__name__
    shape, dtype = found
    return f"{dtype}[{', '.join(map(str, shape))}]"


def array_problem(
    x: Any, shapes: Iterable[tuple[int, ...]], kinds: str = "f", dtype: str | None = None
) -> str | None:
    """Why `x` is not an array of one of `shapes` with a dtype of numpy kind among `kinds`
    ("f" float, "i" int, "u" unsigned, "b" bool) or exactly `dtype`; None if it is."""
    shapes = [tuple(s) for s in shapes]
    found = aval(x)
    wanted = " or ".join(f"[{', '.join(map(str, s))}]" for s in shapes)
    expected = f"{dtype or _kind_names(kinds)}{wanted}"
    if found is None:
        return f"a {type(x).__name__}; expected an array {expected}"
    shape, name = found
    good_dtype = name == dtype if dtype else _is_numpy(name) and np.dtype(name).kind in kinds
    if shape not in shapes or not good_dtype:
        return f"{describe(x)}; expected {expected}"
    return None


def _kind_names(kinds: str) -> str:
    names = {"f": "float", "i": "int", "u": "uint", "b": "bool"}
    return "/".join(names[k] for k in kinds)


def like_problem(got: Any, expected: Any, what: str) -> str | None:
    """Why pytree `got` differs from `expected` in structure, shapes or dtypes (weak types
    aside: JAX promotes them); None if it does not."""
    got_leaves, got_tree = jax.tree.flatten(got)
    want_leaves, want_tree = jax.tree.flatten(expected)
    if got_tree != want_tree:
        return f"{what} of structure {got_tree}; expected {want_tree}"
    paths = [jax.tree_util.keystr(p) for p, _ in jax.tree_util.tree_flatten_with_path(expected)[0]]
    for path, x, y in zip(paths, got_leaves, want_leaves, strict=True):
        if aval(x) != aval(y):
            return f"{what}{path} {describe(x)}; expected {describe(y)}"
    return None


def metrics_problem(metrics: Any, num_agents: int, what: str = "metrics") -> str | None:
    """Why `metrics` is not a dict of numbers of shape [] or [N] (a metrics.csv column, or
    one per agent); None if it is."""
    if not isinstance(metrics, dict):
        return f"{what} a {type(metrics).__name__}; expected a dict of scalars"
    for name, value in metrics.items():
        problem = array_problem(value, [(), (num_agents,)], kinds="fiub")
        if problem:
            return f"{what}[{name!r}] {problem}"
    return None


def hook_error(owner: Any, method: Any, hook: str, problem: str) -> ContractError:
    """`FILE:LINE: attack NAME: HOOK returned PROBLEM` for `owner`'s hook `method`."""
    return ContractError(f"{location(method)}: {describe_owner(owner)}: {hook} returned {problem}")


def describe_owner(owner: Any) -> str:
    """`attack fake_incentive` / `defense per_giver_cap` / the class name."""
    kind = next((k.__name__.lower() for k in type(owner).__mro__ if k.__name__ in _KINDS), None)
    name = getattr(owner, "name", None)
    return f"{kind} {name}" if kind and isinstance(name, str) else type(owner).__name__


_KINDS = ("Attack", "Defense")


# --- exceptions inside a plugin's code ---------------------------------------------------


def plugin_frame(error: BaseException, files: Iterable[str]) -> traceback.FrameSummary | None:
    """The innermost frame of `error`'s traceback in one of `files` (where the plugin's
    code raised, or called what raised), or None."""
    wanted = {str(Path(f).resolve()) for f in files if f}
    frames = traceback.extract_tb(error.__traceback__)
    return next((f for f in reversed(frames) if str(Path(f.filename).resolve()) in wanted), None)


def first_line(error: BaseException) -> str:
    """`Type: first line of the message` of an exception."""
    text = str(error).strip().splitlines()
    return f"{type(error).__name__}: {text[0]}" if text else type(error).__name__


def code_error(error: BaseException, files: Iterable[str], where: str, fallback: str) -> str:
    """The one line of an exception raised in a plugin's code: `FILE:LINE: Type: message
    (in WHERE)`, at the innermost frame in `files`; where none is, at the innermost frame
    of all (pimbot's code, meeting what the plugin gave it), or `fallback` without a
    traceback."""
    frame = plugin_frame(error, files)
    if frame is None:
        frames = traceback.extract_tb(error.__traceback__)
        frame = frames[-1] if frames else None
    at = f"{frame.filename}:{frame.lineno}" if frame is not None else fallback
    return f"{at}: {first_line(error)} (in {where}; PIMBOT_DEBUG=1 shows the traceback)"


@contextlib.contextmanager
def plugin_code(owner: Any, method: Any, hook: str) -> Iterator[None]:
    """Runs a plugin's `method` (its `hook`): an exception it raises, other than a one-line
    `InvalidParameter`, becomes a `PluginCodeError` at the plugin's file and line."""
    try:
        yield
    except InvalidParameter:
        raise
    except Exception as error:
        files = [source_file(method) or "", source_file(type(owner)) or ""]
        where = f"{describe_owner(owner)}, {hook}()"
        raise PluginCodeError(code_error(error, files, where, location(method))) from error


# --- the checked hooks a registered class runs --------------------------------------------

OutputCheck = Callable[[Any, Any, dict[str, Any]], "str | None"]
"""(the plugin object, what its hook returned, the hook's arguments by the base class's
parameter names) -> why the output breaks the contract, or None."""


def install_checks(cls: type, base: type, checks: dict[str, OutputCheck | None]) -> None:
    """Replaces each method of `checks` that `cls` overrides (relative to `base`) by one that
    runs it under `plugin_code` and checks its output with `checks[name]` (None: no output
    check). The method's values pass through unchanged; the checks read only static shapes
    and dtypes, so a traced program is the same. A method already checked (inherited from a
    registered class) is left as it is."""
    for name, check in checks.items():
        method = getattr(cls, name)
        if getattr(method, "checked_hook", None) or not overrides(cls, base, name):
            continue
        setattr(cls, name, _checked(name, method, inspect.signature(getattr(base, name)), check))


def _checked(name: str, method: Callable, signature: inspect.Signature, check) -> Callable:
    @functools.wraps(method)
    def checked(self, *args, **kwargs):
        with plugin_code(self, method, name):
            out = method(self, *args, **kwargs)
        if check is not None:
            problem = check(self, out, signature.bind(self, *args, **kwargs).arguments)
            if problem:
                raise hook_error(self, method, name, problem)
        return out

    checked.checked_hook = name
    return checked


# --- declared values: learner hyperparameters ---------------------------------------------


def value_problem(default: Any, value: Any) -> str | None:
    """What `value` must be to stand where `default` is (a config field's default): a bool,
    an int, a number (an int or a float), text, or a tuple of such; None if it is (or the
    default says nothing: None, or another kind)."""
    if isinstance(default, tuple):
        item = default[0] if default else None
        wrong = not isinstance(value, tuple) or any(value_problem(item, v) for v in value)
        of = f" of {_PLURALS.get(type(item), type(item).__name__)}" if default else ""
        return f"a tuple{of}, as {default!r}" if wrong else None
    for kind, accepted in ((bool, bool), (int, int), (float, int | float), (str, str)):
        if isinstance(default, kind):
            ok = isinstance(value, accepted) and (kind is bool or not isinstance(value, bool))
            return None if ok else _KIND_WORDS[kind]
    return None


_KIND_WORDS = {bool: "a bool", int: "an int", float: "a number", str: "text (a str)"}
_PLURALS = {bool: "bools", int: "ints", float: "numbers", str: "strs"}


def caller_location() -> str:
    """``FILE:LINE`` of the innermost frame of the current call outside the pimbot package
    (the plugin line that called a declaration), or "" where there is none."""
    frame = inspect.currentframe()
    while frame is not None:
        path = Path(frame.f_code.co_filename).resolve()
        if PACKAGE_DIR not in path.parents and not frame.f_code.co_filename.startswith("<frozen"):
            return f"{frame.f_code.co_filename}:{frame.f_lineno}"
        frame = frame.f_back
    return ""
