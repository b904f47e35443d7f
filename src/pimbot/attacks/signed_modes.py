"""Attack modes that only choose a ±1 sign, made traced so that the modes share a program.

An attack whose static `mode` field is used only through its `sign` (a float) gives its
`program_form` as a subclass with that sign as a traced leaf, `traced_sign`, and the
static mode set to a fixed placeholder: every mode then lowers to one program text.
The subclass is `class ProgramX(TracedSign, X)` declaring `traced_sign: Any = <the
placeholder's sign>`, a data field of the flax struct (a pytree leaf, traced where the
program takes the form as an argument, as an env's `traced_fields` are); `with_traced_sign`
builds it from an X with its constructor.
"""

from __future__ import annotations

import dataclasses
from typing import Any, TypeVar

import jax.numpy as jnp

from pimbot.contracts.attack import Attack

Form = TypeVar("Form", bound=Attack)


def with_traced_sign(attack: Attack, form: type[Form], placeholder: str) -> Form:
    """`form` (a subclass of the attack's class with a `traced_sign` field whose `sign` is
    that field) holding the attack's fields, its mode `placeholder` and its sign traced."""
    fields = {f.name: getattr(attack, f.name) for f in dataclasses.fields(attack)}
    return form(**(fields | {"mode": placeholder, "traced_sign": jnp.float32(attack.sign)}))


class TracedSign:
    """Mixin of a program form: its `sign` is the traced leaf `traced_sign` (a field the
    form declares), and it is its own program form. Listed before the attack's class."""

    @property
    def sign(self) -> Any:
        return self.traced_sign

    def program_form(self):
        return self
