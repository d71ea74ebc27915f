"""The public face is typed: what ``help(amfe)`` lists has annotated parameters and returns."""
import inspect

import amfe


def unannotated(func, owner=""):
    """'name(param)' for each parameter of ``func`` without an annotation, and 'name->'
    when its return has none (self and cls excluded)."""
    sig = inspect.signature(func)
    name = f"{owner}{func.__name__}"
    missing = [f"{name}({p})" for p, par in sig.parameters.items()
               if p not in ("self", "cls") and par.annotation is inspect.Parameter.empty]
    if sig.return_annotation is inspect.Signature.empty and func.__name__ != "__init__":
        missing.append(f"{name}->")
    return missing


def public_callables():
    """(owner prefix, function) of every public function and public method of the face."""
    for name in amfe.__all__:
        value = getattr(amfe, name)
        if inspect.isfunction(value):
            yield "", value
        elif inspect.isclass(value):
            for attr, member in vars(value).items():
                if attr.startswith("_") and attr != "__init__":
                    continue
                if isinstance(member, (classmethod, staticmethod)):
                    member = member.__func__
                if isinstance(member, property):
                    member = member.fget
                if inspect.isfunction(member) and member.__module__.startswith("amfe"):
                    yield f"{name}.", member


def test_every_public_function_and_method_is_annotated():
    missing = [m for owner, func in public_callables() for m in unannotated(func, owner)]
    assert not missing, "unannotated: " + ", ".join(missing)


def test_the_check_sees_a_missing_annotation():
    def f(a: int, b) -> int:
        return a

    def g(a: int):
        return a

    assert unannotated(f) == ["f(b)"] and unannotated(g) == ["g->"]
    assert any(owner == "Surrogate." for owner, _ in public_callables())
