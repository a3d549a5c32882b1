//! The plausibility gate: the one place that decides whether a new force estimate may
//! be felt. Physics bounds it: against a rigid sample the tip cannot bend faster than
//! the stage pushes it, so between two estimates the sensed force changes by at most
//! k x (the stage travel commanded in between) + a few sigmas of the two estimates,
//! k being the cantilever's spring constant (EI = k L^3 / 3).
//!
//! - An estimate within that bound of the last accepted one is accepted.
//! - A larger jump is held ("unconfirmed", not rendered). A jump toward zero force (a
//!   release: the tip springs back, slips, leaves the sample) and the first force after
//!   start are confirmed when `confirm_frames` consecutive held estimates are each
//!   within the bound of the one before: then the newest is accepted and fades in. A
//!   jump away from zero stays held until the commanded travel explains it (the
//!   operator's motion widens the bound), so a false bend that persists, frame after
//!   frame, is never felt.
//! - After a miss (or before any estimate was accepted) the next accepted force fades in.
//! - A force whose angle sigma exceeds `full_sigma_deg` is rendered attenuated, by
//!   (full_sigma / sigma)^2; a vague estimate never buys a larger jump allowance than
//!   one at `full_sigma_deg`.
//!
//! Pure and allocation-free; the haptic loop runs it on each new estimate, with the
//! stage travel it integrated from its own velocity commands ([`TravelLog`](super::timing::TravelLog)).

use super::gains::GateLimits;
use crate::model::Cantilever;

/// One estimate as the gate sees it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Candidate {
    pub force_nn: f64,
    /// The angle's standard error, at least `min_sigma_deg`, degrees.
    pub angle_sigma_deg: f64,
    /// The force's standard error (the angle sigma through the cantilever table), nN.
    pub sigma_nn: f64,
    /// Commanded stage travel (path length, cumulative) up to the frame's capture,
    /// less the stage's settling time: motion after it may show in later frames, um.
    pub travel_before_um: f64,
}

impl Candidate {
    /// An estimate of `force_nn` at the tip angle `angle_deg` (NaN: unknown, derived
    /// from the force) with standard error `angle_sigma_deg` (NaN: unknown, the floor).
    pub fn new(
        force_nn: f64,
        angle_deg: f64,
        angle_sigma_deg: f64,
        limits: &GateLimits,
        cantilever: &Cantilever,
        travel_before_um: f64,
    ) -> Candidate {
        let angle_sigma_deg = if angle_sigma_deg.is_finite() {
            angle_sigma_deg.max(limits.min_sigma_deg)
        } else {
            limits.min_sigma_deg
        };
        let angle_deg = if angle_deg.is_finite() {
            angle_deg
        } else {
            cantilever.angle_from_force_nn(force_nn).value
        };
        // The table's slope over +-sigma (the steeper side).
        let at = |a: f64| cantilever.force_nn(a).value;
        let centre = at(angle_deg);
        let sigma_nn = (at(angle_deg + angle_sigma_deg) - centre)
            .abs()
            .max((centre - at(angle_deg - angle_sigma_deg)).abs());
        Candidate {
            force_nn,
            angle_sigma_deg,
            sigma_nn: if sigma_nn.is_finite() { sigma_nn } else { 0.0 },
            travel_before_um,
        }
    }
}

/// What the gate decided about one estimate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Judgement {
    /// Render `weight` x the force; `fade_in`: ramp to it over `fade_in_ms`.
    Accept { weight: f64, fade_in: bool },
    /// Not rendered: a jump larger than physics allows, not (yet) confirmed.
    Held,
}

/// Counts since start.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct GateCounters {
    /// Estimates held as implausible jumps.
    pub held: u64,
    /// Estimates rendered attenuated for a large sigma.
    pub attenuated: u64,
    /// Jumps accepted after `confirm_frames` agreeing estimates.
    pub confirmed: u64,
}

#[derive(Debug, Clone)]
pub struct Gate {
    limits: GateLimits,
    /// The cantilever's spring constant, nN per um of tip deflection.
    stiffness_nn_per_um: f64,
    accepted: Option<Candidate>,
    /// The newest held estimate and how many agreeing ones led to it.
    streak: Option<(Candidate, u32)>,
    /// A miss since the last accepted estimate: the next one fades in.
    lost: bool,
    counters: GateCounters,
}

impl Gate {
    pub fn new(limits: GateLimits, cantilever: &Cantilever) -> Self {
        let length_m = cantilever.length_um * 1e-6;
        let k_n_per_m = 3.0 * cantilever.flexural_rigidity_n_m2 / (length_m * length_m * length_m);
        Gate {
            limits,
            // 1 N/m = 1e9 nN per 1e6 um.
            stiffness_nn_per_um: k_n_per_m * 1e3,
            accepted: None,
            streak: None,
            lost: true,
            counters: GateCounters::default(),
        }
    }

    /// Judges another probe from here on (`cantilever`, its beam): nothing accepted of
    /// the last one counts, and the first estimate fades in. The counts go on.
    pub fn restart(&mut self, cantilever: &Cantilever) {
        let counters = self.counters;
        *self = Gate::new(self.limits.clone(), cantilever);
        self.counters = counters;
    }

    pub fn set_limits(&mut self, limits: GateLimits) {
        self.limits = limits;
    }

    pub fn limits(&self) -> &GateLimits {
        &self.limits
    }

    pub fn counters(&self) -> GateCounters {
        self.counters
    }

    /// The last accepted estimate.
    pub fn accepted(&self) -> Option<&Candidate> {
        self.accepted.as_ref()
    }

    /// The tip was not found in a frame: the next accepted force fades in.
    pub fn miss(&mut self) {
        self.lost = true;
        self.streak = None;
    }

    /// Judges a detected estimate; `travel_now_um` is the cumulative commanded travel now.
    pub fn judge(&mut self, candidate: Candidate, travel_now_um: f64) -> Judgement {
        let plausible = self
            .accepted
            .is_some_and(|a| self.within_bound(&a, &candidate, travel_now_um));
        if plausible {
            self.streak = None;
            return self.accept(candidate, false);
        }
        let run = match self.streak {
            Some((prev, n)) if self.within_bound(&prev, &candidate, travel_now_um) => n + 1,
            _ => 1,
        };
        if run >= self.limits.confirm_frames && self.confirmable(&candidate) {
            self.streak = None;
            self.counters.confirmed += 1;
            return self.accept(candidate, true);
        }
        self.streak = Some((candidate, run));
        self.counters.held += 1;
        Judgement::Held
    }

    /// The largest plausible change of the force from `from` to `to`, nN.
    pub fn allowed_change_nn(&self, from: &Candidate, to: &Candidate, travel_now_um: f64) -> f64 {
        let travel_um = (travel_now_um - from.travel_before_um).max(0.0);
        // A vague estimate buys no more allowance than one at full_sigma_deg.
        let sigma =
            |c: &Candidate| c.sigma_nn * (self.limits.full_sigma_deg / c.angle_sigma_deg).min(1.0);
        let sigma_nn = sigma(from).hypot(sigma(to));
        self.stiffness_nn_per_um * travel_um + self.limits.sigmas * sigma_nn
    }

    /// Whether agreeing frames alone may confirm a jump to `to`: before anything was
    /// accepted (the probe may start in contact), or toward zero force (a release: the
    /// tip springs back, slips or leaves the sample, no stage motion needed). A jump
    /// away from zero needs the stage to have pushed: it stays held until the commanded
    /// travel explains it, so a false bend that persists is never felt.
    fn confirmable(&self, to: &Candidate) -> bool {
        match &self.accepted {
            None => true,
            Some(from) => {
                let slack_nn = self.limits.sigmas * from.sigma_nn.hypot(to.sigma_nn);
                to.force_nn.abs() <= from.force_nn.abs() + slack_nn
                    && to.force_nn * from.force_nn.signum() >= -slack_nn
            }
        }
    }

    fn within_bound(&self, from: &Candidate, to: &Candidate, travel_now_um: f64) -> bool {
        (to.force_nn - from.force_nn).abs() <= self.allowed_change_nn(from, to, travel_now_um)
    }

    fn accept(&mut self, candidate: Candidate, confirmed: bool) -> Judgement {
        let fade_in = confirmed || self.lost || self.accepted.is_none();
        self.accepted = Some(candidate);
        self.lost = false;
        let weight = (self.limits.full_sigma_deg / candidate.angle_sigma_deg)
            .powi(2)
            .min(1.0);
        if weight < 1.0 {
            self.counters.attenuated += 1;
        }
        Judgement::Accept { weight, fade_in }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cantilever() -> Cantilever {
        // 0.06 N/m, 434.675 um: k = 60 nN/um.
        Cantilever::new(
            434.675,
            Cantilever::rigidity_from_spring_constant(0.06, 434.675),
        )
    }

    fn candidate(force_nn: f64, sigma_deg: f64, travel_before_um: f64) -> Candidate {
        Candidate::new(
            force_nn,
            f64::NAN,
            sigma_deg,
            &GateLimits::default(),
            &cantilever(),
            travel_before_um,
        )
    }

    fn accepted_at(force_nn: f64) -> Gate {
        let mut gate = Gate::new(GateLimits::default(), &cantilever());
        for _ in 0..GateLimits::default().confirm_frames {
            gate.judge(candidate(force_nn, 0.02, 0.0), 0.0);
        }
        assert_eq!(gate.accepted().map(|a| a.force_nn), Some(force_nn));
        gate
    }

    #[test]
    fn force_sigma_comes_from_the_cantilever_table() {
        // Small deflection: F = 2 theta EI / L^2 = 2 theta k L / 3, 304 nN per degree.
        let c = candidate(0.0, 0.1, 0.0);
        let per_deg = 2.0 * 0.06 * 434.675e-6 / 3.0 * 1e9 * 1f64.to_radians();
        assert!((c.sigma_nn / (0.1 * per_deg) - 1.0).abs() < 0.01, "{c:?}");
        assert_eq!(candidate(0.0, f64::NAN, 0.0).angle_sigma_deg, 0.02);
        assert_eq!(candidate(0.0, 0.001, 0.0).angle_sigma_deg, 0.02);
    }

    #[test]
    fn allowed_jump_is_k_times_travel_plus_sigmas() {
        let gate = accepted_at(100.0);
        let from = *gate.accepted().unwrap();
        let to = candidate(100.0, 0.02, 0.0);
        let sigmas_nn = 4.0 * from.sigma_nn.hypot(to.sigma_nn);
        let allowed = gate.allowed_change_nn(&from, &to, 2.0);
        assert!(
            (allowed - (60.0 * 2.0 + sigmas_nn)).abs() < 1e-6,
            "{allowed}"
        );
        // A vague estimate buys no more than one at full_sigma_deg.
        let vague = candidate(100.0, 1.0, 0.0);
        let capped = candidate(100.0, 0.1, 0.0);
        let (v, c) = (
            gate.allowed_change_nn(&from, &vague, 0.0),
            gate.allowed_change_nn(&from, &capped, 0.0),
        );
        assert!((v / c - 1.0).abs() < 0.01, "{v} vs {c}");
    }

    #[test]
    fn a_plausible_change_is_accepted_a_larger_one_held() {
        let mut gate = accepted_at(100.0);
        // 1 um of travel: up to 60 nN plus sigmas.
        let judged = gate.judge(candidate(155.0, 0.02, 0.0), 1.0);
        assert_eq!(
            judged,
            Judgement::Accept {
                weight: 1.0,
                fade_in: false
            }
        );
        let held_before = gate.counters().held;
        assert_eq!(
            gate.judge(candidate(400.0, 0.02, 1.0), 1.0),
            Judgement::Held
        );
        assert_eq!(gate.counters().held, held_before + 1);
        // The next frame back near the accepted force is accepted again.
        assert!(matches!(
            gate.judge(candidate(156.0, 0.02, 1.0), 1.0),
            Judgement::Accept { .. }
        ));
    }

    #[test]
    fn a_release_is_confirmed_after_n_agreeing_frames_and_fades_in() {
        let mut gate = accepted_at(900.0);
        for _ in 1..GateLimits::default().confirm_frames {
            assert_eq!(gate.judge(candidate(0.0, 0.02, 0.0), 0.0), Judgement::Held);
        }
        assert_eq!(
            gate.judge(candidate(0.0, 0.02, 0.0), 0.0),
            Judgement::Accept {
                weight: 1.0,
                fade_in: true
            }
        );
        assert_eq!(gate.counters().confirmed, 2);
        // Frames that disagree with each other never confirm.
        let mut gate = accepted_at(3000.0);
        for (i, force) in [900.0, 1500.0, 700.0, 1200.0, 950.0, 2000.0]
            .iter()
            .enumerate()
        {
            let judged = gate.judge(candidate(*force, 0.02, 0.0), 0.0);
            assert_eq!(judged, Judgement::Held, "frame {i}");
        }
    }

    #[test]
    fn a_persistent_jump_away_from_zero_waits_for_stage_travel() {
        let mut gate = accepted_at(0.0);
        for _ in 0..20 {
            assert_eq!(
                gate.judge(candidate(900.0, 0.02, 0.0), 0.0),
                Judgement::Held
            );
        }
        // Nor across zero to the other side.
        assert_eq!(
            gate.judge(candidate(-900.0, 0.02, 0.0), 0.0),
            Judgement::Held
        );
        // 15 um of commanded travel explain 900 nN at 60 nN/um.
        assert!(matches!(
            gate.judge(candidate(900.0, 0.02, 0.0), 15.0),
            Judgement::Accept { fade_in: false, .. }
        ));
    }

    #[test]
    fn a_reacquired_force_fades_in() {
        let mut gate = accepted_at(200.0);
        gate.miss();
        assert_eq!(
            gate.judge(candidate(205.0, 0.02, 0.0), 0.0),
            Judgement::Accept {
                weight: 1.0,
                fade_in: true
            }
        );
    }

    #[test]
    fn a_large_sigma_is_rendered_attenuated() {
        let mut gate = accepted_at(200.0);
        let Judgement::Accept { weight, .. } = gate.judge(candidate(200.0, 0.3, 0.0), 0.0) else {
            panic!("held");
        };
        assert!((weight - 1.0 / 9.0).abs() < 1e-12, "{weight}");
        assert_eq!(gate.counters().attenuated, 1);
    }
}
