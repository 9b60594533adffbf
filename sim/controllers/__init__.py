"""Controllers behind one protocol (`sim.controllers.base.Controller`): the momentum balance
controller and the fall controller that takes over when balance is lost."""

from sim.controllers.base import Cmrt, Controller, Observation
from sim.controllers.fall import FallController
from sim.controllers.momentum import ControllerParams, GainScheduler, MomentumController

__all__ = ["Cmrt", "Controller", "ControllerParams", "FallController", "GainScheduler",
           "MomentumController", "Observation"]
