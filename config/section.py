"""What every settings section shares (config/settings.py builds the tree): the base model
that forbids unknown keys and infinities, and the bounds of settings that have no natural one."""

from __future__ import annotations

from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field

#: Baud rates the C500C's `siocfg` and the host serial ports both offer
#: (docs/reference/c500c-console.md).
SUPPORTED_BAUDRATES = (9600, 19200, 38400, 57600, 115200)

#: Upper bounds of settings that have no natural one: far beyond any real use, low enough that
#: no product, allocation or timer built from them overflows.
MAX_FRAME_PX = 16_384
MAX_HEAT_W = 1_000.0
MAX_TIMEOUT_S = 3_600.0
MAX_DURATION_S = 366 * 86_400.0  # a year of run clock
#: api.max_connections at most: the file-descriptor budget (deploy/thermocomp.service's
#: LimitNOFILE) is sized from it.
MAX_CONNECTIONS_LIMIT = 4_096

PositiveFloat = Annotated[float, Field(gt=0)]
NonNegativeFloat = Annotated[float, Field(ge=0)]


class Section(BaseModel):
    # allow_inf_nan=False: every float of every section is finite (TOML's inf/nan, 1e400 and
    # an environment "Infinity" are refused naming the field), so no setting can carry an
    # infinity into a timer, a model step or a division
    model_config = ConfigDict(
        extra="forbid", validate_default=True, frozen=True, allow_inf_nan=False
    )
