"""Type names for the sampler code (annotations only; nothing here runs at render time).

Mitsuba's stubs declare the variant's array types twice: ``mi.Float``, ``mi.Bool``,
``mi.UInt32``, ... are classes of their own, while the methods of ``mi.Sampler``
(and free functions such as ``mi.permute_kensler``) are annotated with Dr.Jit's
``drjit.auto.ad`` types. At run time both names denote the variant's one class
(for the LLVM variants that mcrt uses), but a type checker sees unrelated types.
Overrides of Mitsuba's methods therefore accept both spellings.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, TypeAlias

if TYPE_CHECKING:
    import drjit.auto.ad
    import mitsuba as mi

#: A lane mask as Mitsuba passes it to ``next_1d``/``next_2d``: an array of the
#: variant's booleans, or a Python bool (all lanes).
Mask: TypeAlias = "mi.Bool | drjit.auto.ad.Bool | bool"

#: A seed as ``mi.Sampler.seed()`` receives it: a Python int, or a size-1 array.
SeedValue: TypeAlias = "int | mi.UInt32 | drjit.auto.ad.UInt"
