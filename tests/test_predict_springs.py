"""`amfe predict --springs`: a model knows the springs of its labels, a solve uses them, and a
model of other springs is refused (issue 47, item 4)."""
import json

import h5py
import pytest
from cli_fixtures import mutated_checkpoint, run_main, tiny_model

import amfe
from amfe.errors import AmfeError
from amfe.io.result_meta import validate
from amfe.model.continuum_springs import springs_record


@pytest.fixture(scope="module")
def models(tmp_path_factory):
    """(paper model, continuum model, tiny bed, directory): the continuum model is the paper
    one whose data set recorded the continuum springs (its weights are the same)."""
    d = tmp_path_factory.mktemp("springs")
    paper, bed = tiny_model(str(d))
    record = json.dumps(springs_record("continuum"))

    def continuum(ckpt):
        ckpt["dataset"]["springs"] = record
    return paper, mutated_checkpoint(paper, d / "continuum.pt", continuum), bed, d


def test_training_records_the_data_sets_springs(tmp_path):
    from test_training import TINY_ATTRS, write_synthetic

    from amfe.training.predict import Surrogate
    from amfe.training.train import TrainConfig, train_model
    data = write_synthetic(tmp_path / "d.h5", n=40, shape=(1, 5, 5), attrs=TINY_ATTRS)
    with h5py.File(data, "a") as f:
        f.attrs["springs"] = json.dumps(springs_record("continuum"))
    ckpt = train_model(data, TrainConfig(epochs=1, batch_size=8, members=1, seed=1),
                       progress=False, log=lambda line: None)
    sur = Surrogate(ckpt, "m")
    assert sur.springs == springs_record("continuum") and sur.springs["name"] == "continuum"
    assert "continuum springs" in repr(sur)
    with h5py.File(data, "a") as f:   # a data set from before the springs were recorded
        del f.attrs["springs"]
    old = train_model(data, TrainConfig(epochs=1, batch_size=8, members=1, seed=1),
                      progress=False, log=lambda line: None)
    assert Surrogate(old, "m").springs == {"name": "paper"}


def test_the_record_names_the_models_springs_and_the_check_solves_with_them(models):
    paper, continuum, bed, d = models
    code, _, err = run_main(["predict", bed, "--model", continuum, "--check", "-o", d / "c.json"])
    assert code == 0, err
    got = json.loads((d / "c.json").read_text())
    validate(got)
    rec = got["beds"][0]
    assert rec["springs"] == springs_record("continuum")
    cont = amfe.homogenize(bed, springs="continuum")
    plain = amfe.homogenize(bed)
    assert rec["check"]["solver"]["Ex"] == pytest.approx(cont.Ex, rel=1e-6)
    assert abs(cont.Ex / plain.Ex - 1) > 0.02   # the check would see the wrong springs
    code, _, err = run_main(["predict", bed, "--model", paper, "-o", d / "p.json"])
    assert code == 0, err
    assert json.loads((d / "p.json").read_text())["beds"][0]["springs"] == {"name": "paper"}


def test_a_model_of_other_springs_is_refused(models):
    paper, continuum, bed, d = models
    code, _, err = run_main(["predict", bed, "--model", paper, "--springs", "continuum"])
    assert code == 2 and "trained on labels of the paper springs" in err, err
    code, _, err = run_main(["predict", bed, "--model", continuum, "--springs", "paper"])
    assert code == 2 and "continuum springs, not the paper" in err, err
    code, _, err = run_main(["predict", bed, "--stiffness", "--springs", "continuum"])
    assert code == 2 and "no shipped full-stiffness model for the continuum springs" in err
    with pytest.raises(AmfeError, match="springs must be"):
        amfe.predict(bed, springs="voxel")


def test_a_bed_outside_the_continuum_model_is_solved_with_the_continuum_springs(tmp_path):
    from amfe.io.bedfile import write_bed
    bed = amfe.generate_bed(size=(0.8e-3, 0.8e-3, 0.3e-3), seed=3)
    path = tmp_path / "b.h5"
    write_bed(path, bed)
    code, _, err = run_main(["predict", path, "--springs", "continuum", "-o", tmp_path / "o.json"])
    assert code == 2 and "no continuum-spring surrogate for a 0.8 x 0.8 x 0.3 mm bed" in err
    assert "amfe homogenize --springs continuum" in err
    code, _, err = run_main(["predict", path, "--springs", "continuum", "--fallback",
                             "-o", tmp_path / "f.json"])
    assert code == 0, err
    rec = json.loads((tmp_path / "f.json").read_text())["beds"][0]
    assert rec["source"] == "solver" and rec["springs"]["name"] == "continuum"
    assert rec["properties"]["Ex"] == pytest.approx(
        amfe.homogenize(bed, springs="continuum").Ex, rel=1e-6)


def test_the_shipped_continuum_model_covers_only_its_size():
    from amfe.model.bed import Bed
    from amfe.training.shipped import shipped_model_for
    bed = Bed([[1e-4, 1e-4, 1e-4]], [2e-5], {"size": [1.2e-3, 1.2e-3, 0.3e-3]})
    with pytest.raises(AmfeError, match="no shipped continuum-spring model for a 1.2 x 1.2 mm "
                                        "bed .*--springs continuum"):
        shipped_model_for(bed, springs="continuum")
    small = Bed([[1e-4, 1e-4, 1e-4]], [2e-5], {"size": [0.6e-3, 0.6e-3, 0.3e-3]})
    assert shipped_model_for(small).name == "multiscale_small.pt"
