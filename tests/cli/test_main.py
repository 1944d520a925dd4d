"""cli.main: the parser (every command, errors as UsageError), the dispatch, the exit code and single stderr
line for each kind of failure, Python warnings as 'warning:' lines, and the Ctrl-C handler's installation.
A real Ctrl-C to a running bake is tests/cli/test_cli_inputs.py's."""

import signal
import threading
import warnings

import pytest

from usdbake.core.errors import OutputError, UsageError
from usdbake.core.pipeline import ProcessorFailed
from usdbake.cli.console import EXIT_FAILED, EXIT_INTERRUPTED, EXIT_OK, EXIT_USAGE
from usdbake.cli.main import COMMANDS, _interrupted_line, main, make_parser


def run(capsys, *argv) -> tuple[int, str, str]:
    capsys.readouterr()
    code = main([str(a) for a in argv])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def command_that(monkeypatch, name: str, action):
    """Put ``action(args, console)`` in place of the ``name`` command: main's dispatch and error handling
    are what is tested, with the exceptions the real commands raise."""
    monkeypatch.setitem(COMMANDS, name, action)


# --- the parser -------------------------------------------------------------------------------


def test_every_command_has_a_parser_and_a_function():
    parser = make_parser()
    choices = next(a for a in parser._actions if a.dest == "command").choices
    assert set(choices) == set(COMMANDS) == {"bake", "plan", "list", "inspect", "preview", "sky", "serve", "bench"}
    assert make_parser().parse_args(["inspect", "out.usda"]).command == "inspect"


@pytest.mark.parametrize("argv, fragment", [
    ([], "the following arguments are required: command"),
    (["bakery"], "invalid choice: 'bakery'"),
    (["inspect"], "the following arguments are required: output"),
    (["plan", "in.usda", "--threads", "0"], "argument --threads: '0'"),
], ids=["no-command", "unknown-command", "missing-argument", "bad-value-in-a-subcommand"])
def test_a_parse_error_is_a_usage_error_not_an_exit(argv, fragment):
    with pytest.raises(UsageError) as raised:
        make_parser().parse_args(argv)
    assert fragment in str(raised.value)


def test_help_exits_0_with_the_commands(capsys):
    with pytest.raises(SystemExit) as exited:
        main(["--help"])
    assert exited.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith("usage: usdbake") and all(name in out for name in COMMANDS)


# --- exit codes -------------------------------------------------------------------------------


def test_a_command_returns_its_own_exit_code(capsys, monkeypatch):
    seen = []
    command_that(monkeypatch, "inspect", lambda args, console: seen.append(args.output) or 7)
    assert run(capsys, "inspect", "out.usda") == (7, "", "")
    assert seen == ["out.usda"]


@pytest.mark.parametrize("error, code, line", [
    (UsageError("in.usda: no such file"), EXIT_USAGE, "usdbake: error: in.usda: no such file"),
    (ProcessorFailed("radiosity", RuntimeError("kaboom")), EXIT_FAILED,
     "usdbake: processor 'radiosity' failed: RuntimeError: kaboom; no output was written"),
    (OutputError("out.usda: No space left on device"), EXIT_FAILED, "usdbake: error: out.usda: No space left on "
                                                                    "device"),
], ids=["usage", "processor-failed", "output"])
def test_each_failure_is_one_line_on_stderr_and_its_exit_code(capsys, monkeypatch, error, code, line):
    def failing(args, console):
        raise error

    command_that(monkeypatch, "inspect", failing)
    assert run(capsys, "inspect", "out.usda") == (code, "", line + "\n")


def test_markup_in_an_error_is_printed_as_text(capsys, monkeypatch):
    def failing(args, console):
        raise UsageError("[red]not markup[/red] /World/[0]")

    command_that(monkeypatch, "inspect", failing)
    assert run(capsys, "inspect", "x")[2] == "usdbake: error: [red]not markup[/red] /World/[0]\n"


@pytest.mark.parametrize("command, line", [("bake", "usdbake: interrupted; no output was written"),
                                           ("plan", "usdbake: interrupted"), ("", "usdbake: interrupted")])
def test_the_interrupted_line_says_no_output_only_for_bake(command, line):
    assert _interrupted_line(command) == line


def test_an_interrupt_exits_130_with_its_line(capsys, monkeypatch):
    def interrupted(args, console):
        raise KeyboardInterrupt

    command_that(monkeypatch, "inspect", interrupted)
    assert run(capsys, "inspect", "x") == (EXIT_INTERRUPTED, "", "usdbake: interrupted\n")


def test_an_unexpected_error_is_not_swallowed(monkeypatch):
    def broken(args, console):
        raise ZeroDivisionError("a bug is a traceback, not a usage line")

    command_that(monkeypatch, "inspect", broken)
    with pytest.raises(ZeroDivisionError):
        main(["inspect", "x"])


# --- warnings and Ctrl-C ----------------------------------------------------------------------


def test_python_warnings_become_one_warning_line_each_and_the_filter_is_restored(capsys, monkeypatch):
    def warns(args, console):
        warnings.warn("first\nsecond line", UserWarning)
        warnings.warn("[b]kept as text[/b]", RuntimeWarning)
        return EXIT_OK

    command_that(monkeypatch, "inspect", warns)
    before = warnings.showwarning
    code, out, err = run(capsys, "inspect", "x")
    assert code == EXIT_OK and out == ""
    assert err == "warning: first\nsecond line\nwarning: [b]kept as text[/b]\n"
    assert warnings.showwarning is before


def test_ctrl_c_has_its_own_handler_while_a_command_runs_and_the_old_one_after(capsys, monkeypatch):
    seen = []
    command_that(monkeypatch, "inspect", lambda args, console: seen.append(signal.getsignal(signal.SIGINT)) or 0)
    before = signal.getsignal(signal.SIGINT)
    assert run(capsys, "inspect", "x")[0] == 0
    assert seen[0] not in (before, signal.SIG_IGN, signal.SIG_DFL) and callable(seen[0])
    assert signal.getsignal(signal.SIGINT) is before


def test_an_ignored_sigint_stays_ignored(capsys, monkeypatch):
    seen = []
    command_that(monkeypatch, "inspect", lambda args, console: seen.append(signal.getsignal(signal.SIGINT)) or 0)
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)  # a background job
    try:
        run(capsys, "inspect", "x")
    finally:
        signal.signal(signal.SIGINT, previous)
    assert seen == [signal.SIG_IGN]


def test_off_the_main_thread_no_handler_is_installed(monkeypatch):
    seen, codes = [], []
    command_that(monkeypatch, "inspect", lambda args, console: seen.append(signal.getsignal(signal.SIGINT)) or 0)
    before = signal.getsignal(signal.SIGINT)
    worker = threading.Thread(target=lambda: codes.append(main(["inspect", "x"])))  # a host application's thread
    worker.start()
    worker.join(60)
    assert codes == [0] and seen == [before]


def test_the_first_ctrl_c_says_it_stops_once_the_work_returns_then_exits_130(capsys, monkeypatch):
    def pressed_once(args, console):
        signal.getsignal(signal.SIGINT)(signal.SIGINT, None)  # what the interpreter calls on a SIGINT
        return EXIT_OK  # not reached: the handler raises

    command_that(monkeypatch, "inspect", pressed_once)
    code, out, err = run(capsys, "inspect", "x")
    assert (code, out) == (EXIT_INTERRUPTED, "")
    assert err.splitlines() == ["usdbake: interrupting once the work under way returns (Ctrl-C again to stop now)",
                                "usdbake: interrupted"]
