"""Results read back: :func:`read_result` for every JSON amfe writes (docs/model.md, section 6).

``amfe homogenize`` writes one :class:`~amfe.io.result.Result` (any boundary
condition, the frame or the voxel model), ``--bc all`` a set of them beside
their gaps, and ``amfe predict`` its predictions. Each reads back into the
object that wrote it, and writing that again gives the same JSON, byte for
byte (tests/test_readback.py).
"""
import os
from dataclasses import dataclass, field

from amfe.errors import AmfeError
from amfe.io.atomic import write_json
from amfe.io.result import Result, load_json
from amfe.vocab import CONSTANT_NAMES


@dataclass
class ResultSet:
    """The results of ``amfe homogenize --bc all``: {bc: :class:`Result`} and the gaps.

    results: one Result per condition, in the order solved; extra: the bed's
    header, ``bc`` ("all") and the gaps between the conditions (energy_gap,
    relative_gap; docs/model.md, section 9). ``result_set["kubc"]`` is KUBC's.
    """

    results: dict
    extra: dict = field(default_factory=dict)

    def __getitem__(self, bc: str) -> Result:
        try:
            return self.results[bc]
        except KeyError:
            raise KeyError(f"no {bc!r} result here; the conditions are "
                           f"{', '.join(self.results)}") from None

    def __iter__(self):
        return iter(self.results)

    def __len__(self) -> int:
        return len(self.results)

    def to_dict(self) -> dict:
        """The JSON layout amfe writes: the header, bc, the gaps, then the conditions."""
        return {**self.extra, "conditions": {n: r.to_dict() for n, r in self.results.items()}}

    def to_json(self, path: str | os.PathLike) -> None:
        """Write :meth:`to_dict` to ``path`` atomically."""
        write_json(path, self.to_dict())

    def __repr__(self) -> str:
        lines = [f"ResultSet({', '.join(self.results)}; energy gap "
                 f"{self.extra.get('energy_gap', float('nan')):.3g})"]
        head = "        " + "".join(f"{n:>12s}" for n in self.results)
        lines.append(head)
        for name in CONSTANT_NAMES[:6]:
            values = [r.properties[name] for r in self.results.values()]
            scale = 1e9 if name.startswith(("E", "G")) else 1.0
            lines.append(f"  {name:6s}" + "".join(f"{v / scale:12.4f}" for v in values))
        return "\n".join(lines)


@dataclass
class Predictions:
    """What ``amfe predict -o`` wrote: one record (a dict, as in the JSON) per bed.

    extra: the file's own keys (schema_version, command); flat: the file held
    one bed's record at its top level (the layout before ``{"beds": [...]}``).
    """

    beds: list
    extra: dict = field(default_factory=dict)
    flat: bool = False

    def __getitem__(self, k: int) -> dict:
        return self.beds[k]

    def __len__(self) -> int:
        return len(self.beds)

    def to_dict(self) -> dict:
        """The JSON layout the file had."""
        return dict(self.beds[0]) if self.flat else {**self.extra, "beds": list(self.beds)}

    def to_json(self, path: str | os.PathLike) -> None:
        """Write :meth:`to_dict` to ``path`` atomically."""
        write_json(path, self.to_dict())


def read_result(path: str | os.PathLike) -> Result | ResultSet | Predictions:
    """The result amfe wrote to the JSON file ``path``: a :class:`Result` (``homogenize``), a
    :class:`ResultSet` (``homogenize --bc all``) or :class:`Predictions` (``predict``).

    AmfeError, naming the file, for one that is missing, not JSON, or not amfe's.
    """
    data = load_json(path)
    if data.get("command") == "predict":
        if "beds" in data:
            return Predictions(data["beds"], {k: v for k, v in data.items() if k != "beds"})
        return Predictions([data], flat=True)
    if data.get("bc") != "all":
        return Result.from_json(path)
    try:
        results = {n: Result.from_dict(d) for n, d in data["conditions"].items()}
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise AmfeError(f"{os.fspath(path)} is not a complete amfe result "
                        f"({type(exc).__name__}: {exc})") from None
    return ResultSet(results, {k: v for k, v in data.items() if k != "conditions"})
