"""``--help`` that states every option's default, shared by the console scripts.

A newcomer reading ``uav-sitl vehicle --help`` saw ``--port PORT  UDP port of the first
vehicle`` and had to read the code to learn it was 14550. argparse's own
``ArgumentDefaultsHelpFormatter`` would say it, but also ``(default: None)`` for options whose
absence means something the help already explains, ``(default: False)`` for every switch, and
a second default where the text gives one. This one adds ``(default X)`` only where the help
does not mention a default and there is a value to show.
"""

from __future__ import annotations

import argparse

__all__ = ["DefaultsFormatter", "DefaultsRawFormatter"]


class DefaultsFormatter(argparse.HelpFormatter):
    """Appends ``(default X)`` to an option's help unless it says its default already, the
    default is empty (None, False, an empty list) or the option is a switch."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        text = action.help or ""
        default = action.default
        if (not action.option_strings or action.nargs == 0 or "default" in text
                or default is None or default is argparse.SUPPRESS
                or isinstance(default, bool) or default == []):
            return action.help
        return f"{text} (default %(default)s)"  # argparse shows no line without a help


class DefaultsRawFormatter(DefaultsFormatter, argparse.RawDescriptionHelpFormatter):
    """The same, keeping the description's and epilog's line breaks (command lists,
    examples)."""
