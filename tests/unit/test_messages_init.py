"""Messages' quick ``__init__`` (messages._message) builds what ``@dataclass(frozen=True)`` builds."""

import dataclasses

import numpy as np
import pytest

from fxswarm.core import messages as m


def _twin(cls):
    """The same fields as a plain frozen dataclass: the reference the quick init must match."""
    spec = [(f.name, f.type, dataclasses.field(default=f.default) if f.default is not dataclasses.MISSING
             else dataclasses.field(default_factory=f.default_factory) if f.default_factory is not dataclasses.MISSING
             else dataclasses.field()) for f in dataclasses.fields(cls)]
    return dataclasses.make_dataclass(cls.__name__, spec, frozen=True)


def _arguments(cls):
    """One value per field: distinct, so a field set from the wrong argument shows."""
    out = []
    for i, f in enumerate(dataclasses.fields(cls)):
        out.append(np.full(3, float(i)) if "ndarray" in str(f.type) else i)
    return out


@pytest.mark.parametrize("cls", list(m.KINDS.values()), ids=list(m.KINDS))
def test_quick_init_sets_every_field_as_the_dataclass_does(cls):
    twin = _twin(cls)
    names = [f.name for f in dataclasses.fields(cls)]
    args = _arguments(cls)
    required = [f for f in dataclasses.fields(cls)
                if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING]
    for given in (args, args[:len(required)]):  # every field given, then the defaults taken
        ours, ref = cls(*given), twin(*given)
        for name in names:
            a, b = getattr(ours, name), getattr(ref, name)
            assert type(a) is type(b) and np.array_equal(a, b), name
        assert set(ours.__dict__) == set(names)
    keywords = dict(zip(names, args))
    assert repr(cls(**keywords)) == repr(cls(*args))
    with pytest.raises(TypeError):
        cls(*args[:len(required) - 1])
    with pytest.raises(TypeError):
        cls(*args, nonsense=1)


@pytest.mark.parametrize("cls", list(m.KINDS.values()), ids=list(m.KINDS))
def test_messages_stay_frozen(cls):
    msg = cls(*_arguments(cls))
    with pytest.raises(dataclasses.FrozenInstanceError):
        msg.tick = 99
    assert msg.tick != 99


def test_a_default_factory_gives_each_message_its_own_value():
    args = _arguments(m.WorldState)[:11]
    a, b = m.WorldState(*args), m.WorldState(*args)
    assert a.link_age.dtype == np.int64 and a.link_age.shape == (0,)
    assert a.link_age is not b.link_age
