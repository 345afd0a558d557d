"""The command line from a new user's side: a sample count or percentage Blender would clamp
without a word is refused by the argument parser (exit 2), naming the argument."""

import pytest

from restframe_addon.__main__ import build_parser


@pytest.mark.parametrize("args, message", [
    (("--samples", "0"), "argument --samples: must be at least 1 (got 0)"),
    (("--samples", "-3"), "argument --samples: must be at least 1"),
    (("--samples", str((1 << 16) + 1)), "argument --samples: must be at most 65536"),
    (("--percentage", "0"), "argument --percentage: must be at least 1 (got 0)"),
    (("--percentage", "-5"), "argument --percentage: must be at least 1"),
    (("--percentage", "100000"), "argument --percentage: must be at most 32767 (got 100000)"),
    (("--percentage", "half"), "argument --percentage: not a whole number: 'half'"),
])
def test_counts_blender_would_clamp_are_refused_by_the_parser(capsys, args, message):
    with pytest.raises(SystemExit) as stop:
        build_parser().parse_args(["render", "file.blend", "-o", "out.png", *args])
    assert stop.value.code == 2
    assert message in capsys.readouterr().err


@pytest.mark.parametrize("args, value", [(("--samples", "1"), 1), (("--samples", "65536"), 65536),
                                         (("--percentage", "1"), 1), (("--percentage", "32767"), 32767)])
def test_the_limits_themselves_are_accepted(args, value):
    parsed = build_parser().parse_args(["render", "file.blend", "-o", "out.png", *args])
    assert getattr(parsed, args[0][2:]) == value
