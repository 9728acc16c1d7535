"""reings.config: RunConfig's checks, its TOML form (load(write(c)) == c), and the `reings run` /
`reings eval` options generated from it (every field reachable, help from the field docs,
command line over --config)."""
from __future__ import annotations

import dataclasses
import math
import tomllib
from dataclasses import dataclass, fields

import pytest

from reings import config as C
from reings.cli import EVAL_SETS, build_parser, config_from_args, main, option_name
from reings.config import OutputConfig, ReInGSConfig, RunConfig, from_dict, leaf_fields, to_toml
from reings.io import toml


def _roundtrip(c):
    text = to_toml(c)
    tomllib.loads(text)  # the standard reader accepts it as it is
    return from_dict(RunConfig, toml.loads(text))


NON_DEFAULT = [
    RunConfig(),
    RunConfig().resolved(),
    RunConfig(method="reings-no-ivps-no-cvps", data="/some where/fern", dataset="llff", factor=4, views=2, seed=7,
              device="cuda:1", preset="paper", iterations=(100, 300, 600), depth_prior="onnx:/m/dpt.onnx",
              extent="frusta", init_points=2000, sh_degree=1, max_gaussians=50_000, depth_smooth=0.0,
              reings=ReInGSConfig(gamma=1.25, beta1=1e-300, beta2=1.7976931348623157e308, min_init_points=1,
                                  delta=0.0, ivps_fraction=1.0, ivps_hard_opacity=0.5, ivps_min_alpha=1.0,
                                  ivps_depth="hard", cvps_fraction=0.4, final_prune=0.0, ehps=False),
              output=OutputConfig(out="runs/x", lpips=False, eval_every=0, checkpoint_every=1, prune_curve=True)),
    RunConfig(method="3dgs", iterations=(6000,), data='odd "quoted" \\ path\ttab\x7f\x01 ünï', depth_smooth=0.25),
    RunConfig(method="dngaussian", iterations=(1, 2, 3)).resolved(),  # the baselines keep the last count
]


@pytest.mark.parametrize("c", NON_DEFAULT, ids=range(len(NON_DEFAULT)))
def test_toml_round_trip(c):
    back = _roundtrip(c)
    assert back == c
    assert isinstance(back.iterations, (tuple, type(None))) and type(back.reings.beta1) is float


def test_toml_none_is_a_comment_and_absent_is_the_default():
    text = to_toml(RunConfig())
    assert "# max_gaussians: not set" in text and "\nmax_gaussians" not in text
    assert "[reings]" in text and "[output]" in text
    assert "# EHPS: expansion of the SfM box about its centre\ngamma = 1.4" in text  # the field doc above it

    @dataclass(frozen=True)
    class WithDefault:
        x: int | None = 3

    with pytest.raises(ValueError, match="x: None cannot be written"):
        toml.dumps(WithDefault(x=None))


def test_toml_writer_values():
    assert toml.value(float("inf")) == "inf" and toml.value(-math.inf) == "-inf" and toml.value(math.nan) == "nan"
    assert toml.value((1, 2)) == "[1, 2]" and toml.value(True) == "true"
    assert tomllib.loads("a = " + toml.value(0.1 + 0.2))["a"] == 0.1 + 0.2
    s = 'a"b\\c\nd\x00\x7fé'
    assert tomllib.loads("a = " + toml.string(s))["a"] == s


def test_values_are_checked_and_normalised():
    c = RunConfig(method="Reings-No-Ehps", iterations=7, views=__import__("numpy").int64(4), data=__import__("pathlib").Path("x"))
    assert c.method == "reings" and not c.reings.ehps and c.label == "reings-no-ehps"
    assert c.iterations == (7,) and type(c.views) is int and c.data == "x"
    assert c.resolved().iterations == (7, 7, 7) and c.resolved().sh_degree == 0
    assert c.stage_iterations() == {"coarse": 7, "fine": 7, "final": 7}
    assert RunConfig(method="dngaussian", preset="paper").stage_iterations() == {"dngaussian": 6000}
    assert RunConfig(preset="paper").resolved().sh_degree == 1
    bad = [({"views": 1}, "views"), ({"views": True}, "views"), ({"preset": "slow"}, "preset"),
           ({"iterations": (1, 2)}, "iterations"), ({"iterations": (0,)}, "iterations"), ({"sh_degree": 4}, "sh_degree"),
           ({"depth_smooth": -1.0}, "depth_smooth"), ({"method": "nerf"}, "unknown method"),
           ({"dataset": "kitti"}, "dataset"), ({"factor": 0}, "factor")]
    for kw, why in bad:
        with pytest.raises(ValueError, match=why):
            RunConfig(**kw)
    for kw, why in [({"cvps_fraction": 0.0}, "cvps_fraction"), ({"final_prune": 1.0}, "final_prune"),
                    ({"ivps_depth": "median"}, "ivps_depth"), ({"ehps": 1}, "ehps")]:
        with pytest.raises(ValueError, match=why):
            ReInGSConfig(**kw)
    with pytest.raises(ValueError, match="eval_every"):
        OutputConfig(eval_every=-1)


def test_run_config_keywords():
    c = C.run_config(method="reings-no-cvps", cvps_fraction=0.4, out="o", with_lpips=False, eval_every=0,
                     reings_config=ReInGSConfig(ivps=False))
    assert c.label == "reings-no-ivps-no-cvps" and c.reings.cvps_fraction == 0.4
    assert c.output == OutputConfig(out="o", lpips=False, eval_every=0)
    assert C.run_config(c, views=2) == dataclasses.replace(c, views=2)
    with pytest.raises(TypeError, match="unexpected keyword argument 'gama'"):
        C.run_config(gama=1.0)


def test_every_field_is_documented_and_named_once():
    leaves = list(leaf_fields())
    assert all(f.metadata.get("help") for _, f, _ in leaves)
    names = [p.rsplit(".", 1)[-1] for p, _, _ in leaves]
    assert len(names) == len(set(names))  # run(**keywords) takes leaf names
    opts = [option_name(p, f) for p, f, _ in leaves]
    assert len(opts) == len(set(opts))
    for cls in (C.TrainConfig, C.OptimConfig, C.LossConfig, C.DensifyConfig):  # the fit recipe too
        assert all(f.metadata.get("help") for f in fields(cls)), cls
    # the datasets RunConfig accepts are the loader's
    from reings.data.types import KINDS

    assert set(C.DATASETS) == set(KINDS)


def _argv(c: RunConfig, skip=()) -> list:
    """Command-line options that set every leaf of `c` (the inverse of the generated parser)."""
    argv = []
    for path, f, tp in leaf_fields():
        if path in skip:
            continue
        v = c
        for part in path.split("."):
            v = getattr(v, part)
        name = option_name(path, f)
        if isinstance(v, bool):
            argv.append(name if v else "--no-" + name[2:])
        elif v is None:
            argv += [name, "none"]
        elif isinstance(v, tuple):
            argv += [name, ",".join(map(str, v))]
        else:
            argv += [name, repr(v) if isinstance(v, float) else str(v)]
    return argv


def test_every_field_reachable_from_run_and_eval():
    c = NON_DEFAULT[2]
    assert config_from_args(build_parser().parse_args(["run", *_argv(c)])) == c
    a = build_parser().parse_args(["eval", "--out", "x", *_argv(c, skip=EVAL_SETS)])
    # eval sets the method (c's switches come from --no-ehps ...), views, data and out per run
    assert config_from_args(a) == dataclasses.replace(c, views=3, data=None, output=dataclasses.replace(c.output, out=None))
    # options given as "none" unset an optional field
    b = config_from_args(build_parser().parse_args(["run", "--sh-degree", "none", "--iterations", "5"]))
    assert b.sh_degree is None and b.iterations == (5,)


def test_help_comes_from_the_field_docs(capsys):
    with pytest.raises(SystemExit):
        main(["run", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    for path, f, _ in leaf_fields():
        assert option_name(path, f) in text
        assert " ".join(f.metadata["help"].split())[:40] in text.replace("%%", "%"), path


@pytest.mark.parametrize("argv,needles", [
    (["--sh-degree", "4"], ["--sh-degree", "must be one of 0, 1, 2, 3"]),
    (["--ivps-depth", "median"], ["--ivps-depth", "expected, hard"]),
    (["--cvps-fraction", "0"], ["--cvps-fraction", "(0, 1]"]),
    (["--factor", "x"], ["--factor", "expected an integer"]),
    (["--ehps-gamma", "-1"], ["--ehps-gamma", "> 0"]),
    (["--checkpoint-every", "0"], ["--checkpoint-every", ">= 1"]),
    (["--max-gaussians", "0"], ["--max-gaussians", ">= 1"]),
])
def test_bad_values_exit_2_naming_the_option(argv, needles, tmp_path, capsys):
    with pytest.raises(SystemExit) as e:
        main(["run", "--out", str(tmp_path / "o"), *argv])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert all(n in err for n in needles), err
    assert not (tmp_path / "o").exists()


def test_config_file_then_command_line(tmp_path, monkeypatch, capsys):
    from reings import pipeline

    seen = []

    def fake_run(config, **kw):
        seen.append((config, kw))
        return pipeline.RunResult(None, {"mean": {"psnr": 1.0}, "method": config.label, "data": "procedural",
                                         "views": config.views, "device": config.device,
                                         "seconds": {"method": 0.0, "total": 0.0}, "gaussians": {}})

    monkeypatch.setattr(pipeline, "run", fake_run)
    f = tmp_path / "run.toml"
    f.write_text(to_toml(NON_DEFAULT[2]))
    assert main(["run", "--config", str(f), "--quiet"]) == 0  # out from the file
    assert seen[-1][0] == NON_DEFAULT[2] and seen[-1][1] == {"overwrite": False, "quiet": True}
    assert main(["run", "--config", str(f), "--views", "3", "--ivps", "--cvps-fraction", "0.3",
                 "--out", str(tmp_path / "o"), "--overwrite"]) == 0
    c = seen[-1][0]
    assert c.views == 3 and c.reings.ivps and not c.reings.cvps and c.reings.cvps_fraction == 0.3
    assert c.output.out == str(tmp_path / "o") and c.seed == 7 and seen[-1][1]["overwrite"] is True
    # a partial file: the rest are the defaults
    f.write_text('method = "dngaussian"\n[reings]\nfinal_prune = 0.0\n')
    assert main(["run", "--config", str(f), "--out", "o"]) == 0
    assert seen[-1][0] == RunConfig(method="dngaussian", reings=ReInGSConfig(final_prune=0.0),
                                    output=OutputConfig(out="o"))
    n = len(seen)
    for text, needle in [("views = 1\n", "views"), ("[reings]\ngama = 1.0\n", "unknown key 'reings.gama'"),
                         ("views = \n", str(f)), ("iterations = [1, 2]\n", "iterations"),
                         ('depth_smooth = "x"\n', "depth_smooth")]:
        f.write_text(text)
        assert main(["run", "--config", str(f), "--out", "o"]) == 2
        err = capsys.readouterr().err
        assert err.startswith("reings: error:") and needle in err and str(f) in err, err
    assert main(["run", "--config", str(tmp_path / "missing.toml"), "--out", "o"]) == 2
    assert "missing.toml" in capsys.readouterr().err
    with pytest.raises(SystemExit):  # no --out anywhere
        main(["run"])
    assert len(seen) == n


def test_docs_options_table_is_current():
    from pathlib import Path

    from reings.cli import options_markdown

    doc = (Path(__file__).resolve().parents[1] / "docs" / "pipeline.md").read_text()
    table = doc.split("<!-- options:begin -->\n", 1)[1].split("<!-- options:end -->", 1)[0]
    assert table == options_markdown(), "regenerate docs/pipeline.md's options table (reings.cli.options_markdown)"
