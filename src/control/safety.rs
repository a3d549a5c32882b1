//! The safety rules of teleoperation as one state machine, evaluated every haptic tick:
//!
//! - a stale, undetected or unconfirmed estimate blocks motion toward the sample (the
//!   sensed force fades, see [`super::Controller`]); so do frames too slow for force
//!   feedback (a slow scan);
//! - a sensed force above the limit blocks motion that would press harder;
//! - a lost haptic device or a failed DAQ write is a fault: zero velocity at once;
//! - after any stop or fault, motion resumes only once the stylus is back at the centre
//!   (deadman re-engage). A block of the pressing direction is likewise latched until the
//!   stylus has been re-centred, so a fresh estimate never restarts an approach by itself.

use super::gains::SafetyLimits;

/// Where the teleoperation stands.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SafetyState {
    /// No motion until the operator brings the stylus back to the centre.
    WaitingForCentre,
    /// Motion follows the stylus (possibly with the pressing direction blocked).
    Engaged,
    /// The haptic device is lost or erroring: no motion, forces off.
    HapticFault,
    /// Writing the stage command failed: outputs at zero until a write succeeds again.
    DaqFault,
}

impl SafetyState {
    pub fn as_str(self) -> &'static str {
        match self {
            SafetyState::WaitingForCentre => "waiting-for-centre",
            SafetyState::Engaged => "engaged",
            SafetyState::HapticFault => "haptic-fault",
            SafetyState::DaqFault => "daq-fault",
        }
    }
}

/// Why motion that presses on the sample is refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PressBlock {
    /// No fresh, detected estimate: we do not know the force.
    Stale,
    /// The sensed force is above `max_contact_force_nn`.
    ForceLimit,
    /// Frames come further apart than `max_frame_period_ms` (a slow scan): no force
    /// feedback, positioning only.
    SlowFrames,
}

impl PressBlock {
    pub fn as_str(self) -> &'static str {
        match self {
            PressBlock::Stale => "stale-estimate",
            PressBlock::ForceLimit => "force-limit",
            PressBlock::SlowFrames => "slow-frames",
        }
    }
}

/// Event counts since start.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SafetyCounters {
    /// Transitions from a fresh estimate to a stale or undetected one.
    pub stale_events: u64,
    /// Entries into a fault state (haptic or DAQ).
    pub faults: u64,
    /// Transitions into refusing motion because of the contact force limit.
    pub force_limit_events: u64,
}

/// What the safety rules allow this tick.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Verdict {
    pub state: SafetyState,
    /// Motion along the pressing direction (times `press_sign`) is refused.
    pub press_block: Option<PressBlock>,
    /// +1: pressing harder is moving along the press direction; -1 when an adhesion
    /// (pulling) force is over the limit and pulling harder is the refused motion.
    pub press_sign: f64,
    /// Whether the estimate may be rendered as fresh this tick.
    pub fresh: bool,
}

/// Inputs the rules look at, already reduced to facts.
#[derive(Debug, Clone, Copy)]
pub struct Facts {
    pub haptic_ok: bool,
    pub daq_ok: bool,
    /// The stylus is within the re-centre radius.
    pub centred: bool,
    /// An accepted estimate, the newest detected, not stale (see
    /// [`super::timing::FrameTiming::stale_after_s`]).
    pub fresh: bool,
    /// Frames come too slowly for force feedback (never counted as stale events).
    pub slow_frames: bool,
    /// The contact force of the newest fresh estimate (positive = pressing), nN.
    pub contact_nn: f64,
}

#[derive(Debug, Clone)]
pub struct Safety {
    limits: SafetyLimits,
    state: SafetyState,
    was_fresh: bool,
    latched: Option<PressBlock>,
    latched_sign: f64,
    counters: SafetyCounters,
}

impl Safety {
    pub fn new(limits: SafetyLimits) -> Self {
        Safety {
            limits,
            state: SafetyState::WaitingForCentre,
            was_fresh: false,
            latched: Some(PressBlock::Stale),
            latched_sign: 1.0,
            counters: SafetyCounters::default(),
        }
    }

    pub fn set_limits(&mut self, limits: SafetyLimits) {
        self.limits = limits;
    }

    pub fn limits(&self) -> &SafetyLimits {
        &self.limits
    }

    pub fn counters(&self) -> SafetyCounters {
        self.counters
    }

    pub fn state(&self) -> SafetyState {
        self.state
    }

    /// Force a stop (e.g. on shutdown or a gain reload): motion needs a re-centre.
    pub fn stop(&mut self) {
        if matches!(self.state, SafetyState::Engaged) {
            self.state = SafetyState::WaitingForCentre;
        }
    }

    pub fn evaluate(&mut self, facts: Facts) -> Verdict {
        self.update_faults(facts);
        self.update_freshness(facts);
        self.update_force_limit(facts);
        if self.state == SafetyState::WaitingForCentre && facts.centred {
            self.state = SafetyState::Engaged;
        }
        // Re-centring clears a latched block once its cause is gone.
        if facts.centred && self.cause_cleared(facts) {
            self.latched = None;
        }
        Verdict {
            state: self.state,
            press_block: self.latched,
            press_sign: self.latched_sign,
            fresh: facts.fresh,
        }
    }

    fn update_faults(&mut self, facts: Facts) {
        let fault = if !facts.haptic_ok {
            Some(SafetyState::HapticFault)
        } else if !facts.daq_ok {
            Some(SafetyState::DaqFault)
        } else {
            None
        };
        match fault {
            Some(f) => {
                if self.state != f {
                    if !matches!(self.state, SafetyState::HapticFault | SafetyState::DaqFault) {
                        self.counters.faults += 1;
                    }
                    self.state = f;
                }
            }
            None => {
                if matches!(self.state, SafetyState::HapticFault | SafetyState::DaqFault) {
                    self.state = SafetyState::WaitingForCentre;
                }
            }
        }
    }

    fn update_freshness(&mut self, facts: Facts) {
        if !facts.fresh {
            if self.was_fresh && !facts.slow_frames {
                self.counters.stale_events += 1;
            }
            if self.latched != Some(PressBlock::ForceLimit) {
                self.latched = Some(if facts.slow_frames {
                    PressBlock::SlowFrames
                } else {
                    PressBlock::Stale
                });
                self.latched_sign = 1.0;
            }
        }
        self.was_fresh = facts.fresh;
    }

    fn update_force_limit(&mut self, facts: Facts) {
        if facts.fresh && facts.contact_nn.abs() > self.limits.max_contact_force_nn {
            if self.latched != Some(PressBlock::ForceLimit) {
                self.counters.force_limit_events += 1;
            }
            self.latched = Some(PressBlock::ForceLimit);
            self.latched_sign = facts.contact_nn.signum();
        }
    }

    fn cause_cleared(&self, facts: Facts) -> bool {
        match self.latched {
            None => true,
            Some(PressBlock::Stale | PressBlock::SlowFrames) => facts.fresh,
            Some(PressBlock::ForceLimit) => {
                facts.fresh && facts.contact_nn.abs() <= self.limits.max_contact_force_nn
            }
        }
    }
}
