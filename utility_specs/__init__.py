"""The utility evaluation model of thesis ch. 4: messages, utility functions, exact totals."""

from utility_specs.errors import LogError, MessageError, SpecError, UtilitySpecsError
from utility_specs.evaluate import Evaluation, evaluate
from utility_specs.files import builtin_spec, load_spec, read_log
from utility_specs.functions import FUNCTIONS, UtilityFunction, make_function
from utility_specs.log import MissionLog, parse_log
from utility_specs.message import Message, StateHistory, Version
from utility_specs.spec import InfoType, MissionSpec, parse_spec

__all__ = [
    "FUNCTIONS",
    "Evaluation",
    "InfoType",
    "LogError",
    "Message",
    "MessageError",
    "MissionLog",
    "MissionSpec",
    "SpecError",
    "StateHistory",
    "UtilityFunction",
    "UtilitySpecsError",
    "Version",
    "builtin_spec",
    "evaluate",
    "load_spec",
    "make_function",
    "parse_log",
    "parse_spec",
    "read_log",
]
