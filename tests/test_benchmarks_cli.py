"""The benchmark scripts' argument types and entry point: bad input is one error line."""

from __future__ import annotations

import argparse

import pytest

from benchmarks.cli import count, positive_float, positive_int, run_main


def test_argument_types_accept_good_values_and_name_bad_ones() -> None:
    assert positive_int("4096") == 4096 and count("0") == 0 and positive_float("2.5") == 2.5
    for parse, text, message in [
        (positive_int, "0", "must be >= 1, got 0"),
        (positive_int, "1.5", "expected an integer, got '1.5'"),
        (count, "-1", "must be >= 0, got -1"),
        (positive_float, "0", "finite number > 0"),
        (positive_float, "inf", "finite number > 0"),
        (positive_float, "fast", "expected a number, got 'fast'"),
    ]:
        with pytest.raises(argparse.ArgumentTypeError, match=message):
            parse(text)


def test_argparse_reports_a_bad_value_on_one_line(capsys) -> None:
    parser = argparse.ArgumentParser(prog="bench")
    parser.add_argument("--batch", type=positive_int, default=8)
    with pytest.raises(SystemExit) as exit_info:
        parser.parse_args(["--batch", "0"])
    assert exit_info.value.code == 2
    assert capsys.readouterr().err.splitlines()[-1] == (
        "bench: error: argument --batch: must be >= 1, got 0"
    )


def test_run_main_turns_a_value_error_into_one_line(capsys) -> None:
    def main() -> None:
        raise ValueError("unknown preset 'nope'")

    with pytest.raises(SystemExit) as exit_info:
        run_main(main)
    assert exit_info.value.code == 2
    assert capsys.readouterr().err == "error: unknown preset 'nope'\n"
    run_main(lambda: None)  # a main that returns normally exits normally
