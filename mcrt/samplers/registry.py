"""The one registry of samplers: mcrt's, Mitsuba's and any user's.

Every name a command, a study or the Python API accepts is a name here, and
every table of samplers (``mcrt --help``, docs, the contract tests) is derived
from it. A sampler is one of four kinds:

``mcrt``     a plugin shipped in this package (one module per sampler family,
             listed once in :data:`SHIPPED_MODULES`)
``mitsuba``  one of Mitsuba's built-in samplers that mcrt compares against
``user``     a user's ``mi.Sampler`` subclass (usually a :class:`McrtSampler`),
             registered with :func:`register_class`
``points``   point sets from a Python generator (:func:`register_points`) or
             a file (the ``pointset`` plugin), served by :mod:`.pointset`

Each entry states the properties its sampler *claims* (:data:`CLAIMS`), which
``mcrt check`` verifies. Mitsuba knows a Python plugin only per variant: after
a variant switch, :func:`register_with_mitsuba` re-creates the shipped classes
(re-imports their modules), re-runs the registered rebuild hooks (user plugin
files) and registers every entry again.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

import mitsuba as mi

from ..errors import SamplerError

#: What a sampler may claim about its points, and what ``mcrt check`` tests.
CLAIMS: dict[str, str] = {
    "stratified": "at square counts N = k^2, one point in each cell of a k x k grid",
    "latin": "one point in each of the N columns and N rows of an N x N grid",
    "net": "at powers of two N = 2^m, a (0,m,2)-net in base 2: one point in each "
           "elementary interval of area 1/N",
    "min_distance": "toroidal minimum distance >= 0.75 of the hexagonal packing's spacing",
    "progressive": "sample j of a pixel is the same point whatever the sample count",
    "quadrature": "film positions are fixed cell centres (quadrature, not Monte Carlo): "
                  "biased by design; the other dimensions are random",
}

#: Modules of this package that define mcrt's sampler plugins (each lists its
#: classes in ``PLUGINS``), in listing order. A new
#: shipped sampler is one module plus its line here.
SHIPPED_MODULES: tuple[str, ...] = ("jittered", "poisson_disk", "sobol", "zsobol", "pointset")


@dataclass(frozen=True)
class SamplerInfo:
    """One registered sampler.

    ``example`` gives, for a sample count, the plugin parameters the sampler
    needs outside a render (``zsobol``: a film ``width``; ``pointset``: a file).
    """

    name: str
    kind: str
    summary: str
    claims: frozenset[str] = frozenset()
    origin: str = ""
    example: Callable[[int], dict[str, Any]] | None = field(default=None, compare=False)
    #: A digest of a user's sampler code or points ("" for mcrt's and Mitsuba's, whose
    #: versions key every result already): another version is another sampler.
    fingerprint: str = ""

    def example_params(self, spp: int) -> dict[str, Any]:
        """Parameters that let ``mi.load_dict`` build this sampler on its own."""
        return dict(self.example(spp)) if self.example is not None else {}


#: Mitsuba's built-in samplers that mcrt compares against, and what they claim.
MITSUBA_SAMPLERS: dict[str, tuple[str, frozenset[str]]] = {
    "independent": ("Mitsuba: independent uniform points", frozenset()),
    "stratified": ("Mitsuba: jittered k x k strata", frozenset({"stratified"})),
    "multijitter": ("Mitsuba: correlated multi-jittered (Kensler 2013)",
                    frozenset({"stratified", "latin"})),
    "orthogonal": ("Mitsuba: orthogonal-array Latin hypercube", frozenset({"latin"})),
    "ldsampler": ("Mitsuba: low-discrepancy (Sobol' / van der Corput)", frozenset()),
}

#: Registered samplers by name, in registration order.
_ENTRIES: dict[str, SamplerInfo] = {}
#: The class Mitsuba constructs for each entry that is a Python plugin.
_CLASSES: dict[str, type] = {}
#: Functions that re-create user plugins' classes for a newly active variant.
_REBUILDS: dict[str, Callable[[], None]] = {}
#: Variant the shipped classes derive from (None: not imported yet).
_shipped_variant: str | None = None


@dataclass
class _Source:
    """Code that registers samplers while it runs (a plugin file, an entry point)."""

    origin: str
    rebuild: Callable[[], None] | None
    registered: list[str] = field(default_factory=list)


#: The sources running now, innermost last (see :func:`registering`).
_SOURCES: list[_Source] = []
#: Origins of every source that registered something (plugin files, entry points).
_SOURCE_ORIGINS: set[str] = set()


@contextmanager
def registering(origin: str, rebuild: Callable[[], None] | None = None) -> Iterator[list[str]]:
    """While a user's plugin (``origin``: its file, or its entry point) runs:
    its registrations default their ``origin`` to it and (for classes) their
    ``rebuild`` hook to ``rebuild``, which re-runs the plugin after a variant
    switch. Yields the list of names it registers (filled as it runs).

    A plugin may not take a name another plugin registered (a SamplerError);
    running the same plugin again replaces its own names.
    """
    source = _Source(origin, rebuild)
    _SOURCES.append(source)
    try:
        yield source.registered
    finally:
        _SOURCES.pop()


def default_origin(fallback: str = "") -> str:
    """The origin of the plugin running now (see :func:`registering`), else ``fallback``."""
    return _SOURCES[-1].origin if _SOURCES else fallback


#: Registries beside this one that plugins add to (mcrt's integrands): the function of
#: each that forgets what an origin registered there (see :func:`forget`).
_BESIDE: dict[str, Callable[[str], None]] = {}


def note_beside(kind: str, name: str, forget_origin: Callable[[str], None]) -> str:
    """A registration in a registry beside this one (``kind``: ``"integrand"``) by the
    plugin running now: listed among its names as ``"KIND NAME"`` (never a sampler's name),
    and ``forget_origin(origin)`` kept for :func:`forget`. Returns the plugin's origin, ""
    when none is running (the other registry checks its own names)."""
    _BESIDE[kind] = forget_origin
    if not _SOURCES:
        return ""
    _SOURCES[-1].registered.append(f"{kind} {name}")
    _SOURCE_ORIGINS.add(_SOURCES[-1].origin)
    return _SOURCES[-1].origin


def forget(origin: str) -> None:
    """Remove what ``origin`` (a plugin unloaded, or failing) registered in the registries
    beside this one (:func:`note_beside`); its samplers are the plugin loader's to remove."""
    for forget_origin in _BESIDE.values():
        forget_origin(origin)


def _first_line(text: str | None) -> str:
    lines = [line.strip() for line in (text or "").strip().splitlines() if line.strip()]
    return lines[0] if lines else ""


def _summary_of(cls: type) -> str:
    """A class's ``summary`` attribute, else the first line of its docstring."""
    return str(getattr(cls, "summary", "") or _first_line(cls.__doc__) or cls.__name__)


def claims_of(cls: type) -> frozenset[str]:
    """What a sampler class claims: its ``claims`` attribute and ``progressive``."""
    claims = set(getattr(cls, "claims", frozenset()))
    if getattr(cls, "progressive", False):
        claims.add("progressive")
    unknown = claims - set(CLAIMS)
    if unknown:
        raise SamplerError(f"{cls.__name__}: unknown claims {sorted(unknown)}; "
                           f"known: {', '.join(CLAIMS)}")
    return frozenset(claims)


def _check_name(name: str, replace: bool) -> None:
    if not isinstance(name, str) or not name.isidentifier() or not name.islower():
        raise SamplerError(f"sampler name {name!r}: use lower-case letters, digits and '_'")
    taken = _ENTRIES.get(name)
    if taken is not None and not replace and taken.kind in ("mcrt", "mitsuba"):
        raise SamplerError(f"sampler name {name!r} is taken by {taken.kind}'s {name}")


def _check_plugin_name(name: str, origin: str) -> None:
    """A plugin may replace its own names (it runs again after a variant switch),
    not those another plugin registered."""
    taken = _ENTRIES.get(name)
    if taken is not None and taken.origin != origin and taken.origin in _SOURCE_ORIGINS:
        raise SamplerError(f"sampler name {name!r} is taken: {taken.origin} registered it "
                           f"already")


def _add(info: SamplerInfo, cls: type | None) -> None:
    _ENTRIES[info.name] = info
    if cls is not None:
        _CLASSES[info.name] = cls
        _register_one(info.name)


def _register_one(name: str) -> None:
    """Tell Mitsuba (active variant) how to build ``name``: the registry's class
    for it at construction time (so a re-created class takes over at once)."""
    def construct(props: mi.Properties, name: str = name) -> mi.Sampler:
        if variant_hint():  # the classes are another variant's: they would not render here
            raise SamplerError(variant_hint())
        return _CLASSES[name](props)
    mi.register_sampler(name, construct)


def register_class(cls: type, name: str | None = None, *, origin: str = "",
                   example: Callable[[int], dict[str, Any]] | None = None,
                   rebuild: Callable[[], None] | None = None, kind: str = "user",
                   fingerprint: str = "") -> str:
    """Register a ``mi.Sampler`` subclass (constructor ``cls(props)``) under ``name``
    (default: its ``plugin_name``); returns the name.

    ``rebuild`` re-creates and re-registers the class after a variant switch
    (plugin files pass one; see :mod:`mcrt.plugins`). ``fingerprint`` defaults to
    a digest of the plugin file, else of the class's source.
    """
    if isinstance(cls, mi.Sampler):
        raise SamplerError(f"register_class: {type(cls).__name__}(...) is a sampler object: "
                           f"register its class, sampler={type(cls).__name__}")
    if not (isinstance(cls, type) and issubclass(cls, mi.Sampler)):
        raise SamplerError(f"register_class: {cls!r} is not a subclass of mi.Sampler "
                           f"(for numpy point sets use mcrt.register_sampler(name, points=...))")
    name = name or getattr(cls, "plugin_name", "")
    if not name:
        raise SamplerError(f"register_class: {cls.__name__} has no plugin_name; pass a name")
    _check_name(name, replace=kind == "mcrt")
    missing = _missing_methods(cls) if kind != "mcrt" else []
    if missing:
        raise SamplerError(f"{name}: {cls.__name__} does not define {', '.join(missing)}, "
                           f"which renders call (see docs/extending.md)")
    source = _SOURCES[-1] if _SOURCES and kind != "mcrt" else None
    if source is not None:
        origin = origin or source.origin
        rebuild = rebuild if rebuild is not None else source.rebuild
        _check_plugin_name(name, source.origin)
        source.registered.append(name)
        _SOURCE_ORIGINS.add(source.origin)
    origin = origin or cls.__module__
    if kind != "mcrt" and not fingerprint:  # the user's class, not the subclass below
        fingerprint = code_fingerprint(cls, origin)
    if getattr(cls, "plugin_name", name) != name:
        cls = type(cls.__name__, (cls,), {"plugin_name": name})
    _add(SamplerInfo(name, kind, _summary_of(cls), claims_of(cls), origin,
                     example if example is not None else getattr(cls, "example_params", None),
                     fingerprint),
         cls)
    if rebuild is not None:
        _REBUILDS[name] = rebuild
    return name


#: What a user's class must define itself: a McrtSampler subclass its two pure
#: functions (the base's raise NotImplementedError, with no message, in a render);
#: a plain ``mi.Sampler`` subclass Mitsuba's sampler contract (without ``seed`` it
#: rendered a wrong image without a word, without ``clone`` it failed in C++).
_MCRT_METHODS = ("_sample_1d", "_sample_2d")
_SAMPLER_METHODS = ("seed", "next_1d", "next_2d", "clone", "fork")


def _missing_methods(cls: type) -> list[str]:
    """The methods of :data:`_MCRT_METHODS` / :data:`_SAMPLER_METHODS` that
    ``cls`` leaves to mcrt's base class or to Mitsuba's."""
    def owner(method: str) -> type | None:
        return next((c for c in cls.__mro__ if method in vars(c)), None)

    base = f"{__package__}.base"
    if any(c.__name__ == "McrtSampler" and c.__module__ == base for c in cls.__mro__):
        return [m for m in _MCRT_METHODS if getattr(owner(m), "__module__", base) == base]
    return [m for m in _SAMPLER_METHODS
            if getattr(owner(m), "__module__", "mitsuba").split(".")[0] == "mitsuba"]


def code_fingerprint(cls: type, origin: str) -> str:
    """Digest of a user's sampler code: its plugin file's bytes, else its class's
    source (classes of a notebook or script), else "" (no source to read)."""
    import hashlib
    import inspect
    from pathlib import Path

    try:
        data = Path(origin).read_bytes() if origin and Path(origin).is_file() \
            else inspect.getsource(cls).encode()
    except (OSError, TypeError):
        return ""
    return hashlib.sha256(data).hexdigest()[:20]


def _shipped_classes() -> list[type]:
    """mcrt's plugin classes for the active variant (re-imported after a switch)."""
    global _shipped_variant
    modules = [importlib.import_module(f"{__package__}.{name}") for name in SHIPPED_MODULES]
    if _shipped_variant is not None and _shipped_variant != mi.variant():
        base = importlib.import_module(f"{__package__}.base")
        importlib.reload(base)
        modules = [importlib.reload(module) for module in modules]
    _shipped_variant = mi.variant()
    return [cls for module in modules for cls in module.PLUGINS]


def register_with_mitsuba() -> None:
    """Register every sampler with the active variant (see the module docstring)."""
    for cls in _shipped_classes():
        register_class(cls, origin=f"mcrt.samplers.{cls.__module__.rsplit('.', 1)[-1]}",
                       kind="mcrt")
    for name, (summary, claims) in MITSUBA_SAMPLERS.items():
        _ENTRIES.setdefault(name, SamplerInfo(name, "mitsuba", summary, claims, "mitsuba"))
    for rebuild in list(dict.fromkeys(_REBUILDS.values())):
        rebuild()
    for name in _CLASSES:
        _register_one(name)


def variant_hint() -> str:
    """What to do when Mitsuba does not know a registered name because the
    active variant is not the one the samplers were last registered with (it
    knows Python plugins per variant); "" when that is not the case."""
    if _shipped_variant is None or _shipped_variant == mi.variant():
        return ""
    return (f"mcrt's samplers were registered with Mitsuba's {_shipped_variant} variant, not "
            f"the active {mi.variant()}: call mcrt.register() after mi.set_variant()")


def current_class(name: str) -> type:
    """The Python class Mitsuba builds for ``name`` now (KeyError for Mitsuba's)."""
    return _CLASSES[name]


def names(kind: str | None = None) -> tuple[str, ...]:
    """Every registered sampler name (of one ``kind``, if given): ours first, then
    Mitsuba's, then users' in registration order."""
    order = {"mcrt": 0, "mitsuba": 1, "user": 2, "points": 2}
    entries = sorted(_ENTRIES.values(), key=lambda e: order.get(e.kind, 3))
    return tuple(e.name for e in entries if kind is None or e.kind == kind)


def info(name: str) -> SamplerInfo:
    """The entry of ``name``; SamplerError with the known names if there is none."""
    try:
        return _ENTRIES[name]
    except KeyError:
        raise SamplerError(f"unknown sampler {name!r}; choose one of: "
                           f"{', '.join(names())}") from None


def unregister(name: str) -> None:
    """Remove a user's sampler (Mitsuba keeps its constructor; it then refuses)."""
    entry = _ENTRIES.get(name)
    if entry is None or entry.kind in ("mcrt", "mitsuba"):
        raise SamplerError(f"unregister: {name!r} is not a user's sampler")
    del _ENTRIES[name]
    _CLASSES.pop(name, None)
    _REBUILDS.pop(name, None)
