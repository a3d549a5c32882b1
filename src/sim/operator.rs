//! The simulated operator: a virtual hand holding the stylus through a spring-damper,
//! following a scripted task (approach, touch, press to a target force, hold, retract,
//! rest, and again). The hand feels the force the device renders and decides when to
//! move on from it, the way a person would: it knows the centring springs' feel, so what
//! it reads as contact is the rendered force beyond them.
use nalgebra::Vector3;

/// The script and the hand (`[sim.operator]`).
#[derive(Debug, Clone, PartialEq)]
pub struct OperatorParams {
    /// Stylus travel toward the sample while approaching, mm.
    pub approach_mm: f64,
    /// Stylus travel while pressing (slower), mm.
    pub press_mm: f64,
    /// Stylus travel away from the sample while retracting, mm.
    pub retract_mm: f64,
    /// Felt contact force that ends the approach, nN at the tip.
    pub touch_nn: f64,
    /// Felt contact force at which pressing stops and holding starts, nN at the tip.
    pub target_force_nn: f64,
    pub hold_s: f64,
    pub retract_s: f64,
    pub rest_s: f64,
    /// The hand's grip on the stylus.
    pub hand_stiffness_n_per_mm: f64,
    pub stylus_mass_kg: f64,
}

impl Default for OperatorParams {
    fn default() -> Self {
        OperatorParams {
            approach_mm: 15.0,
            press_mm: 15.0,
            retract_mm: 15.0,
            touch_nn: 150.0,
            target_force_nn: 3000.0,
            hold_s: 2.0,
            retract_s: 6.0,
            rest_s: 1.0,
            hand_stiffness_n_per_mm: 0.6,
            stylus_mass_kg: 0.05,
        }
    }
}

/// Where the script is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Phase {
    Centre,
    Approach,
    Press,
    Hold,
    Retract,
    Rest,
}

/// What the hand knows about the device it holds.
#[derive(Debug, Clone, PartialEq)]
pub struct HandModel {
    /// Unit vector in the haptic frame: pushing the stylus this way presses the sample.
    pub press_direction_haptic: Vector3<f64>,
    /// The centring springs it has learnt to feel through.
    pub spring_n_per_mm: Vector3<f64>,
    /// Newtons at the stylus per nN at the tip.
    pub force_scale_n_per_nn: f64,
}

#[derive(Debug, Clone)]
pub struct Operator {
    params: OperatorParams,
    hand: HandModel,
    phase: Phase,
    phase_since_s: f64,
    position_mm: Vector3<f64>,
    velocity_mm_s: Vector3<f64>,
    device_force_n: Vector3<f64>,
    last_s: Option<f64>,
    /// Completed press cycles.
    pub cycles: u32,
}

/// Integration step for the stylus dynamics (the hand is stiff: keep it well resolved).
const MAX_STEP_S: f64 = 2e-4;

impl Operator {
    pub fn new(params: OperatorParams, hand: HandModel) -> Self {
        Operator {
            params,
            hand,
            phase: Phase::Centre,
            phase_since_s: 0.0,
            position_mm: Vector3::zeros(),
            velocity_mm_s: Vector3::zeros(),
            device_force_n: Vector3::zeros(),
            last_s: None,
            cycles: 0,
        }
    }

    pub fn phase(&self) -> Phase {
        self.phase
    }

    pub fn position_mm(&self) -> Vector3<f64> {
        self.position_mm
    }

    pub fn velocity_mm_s(&self) -> Vector3<f64> {
        self.velocity_mm_s
    }

    /// The force the device renders from now on.
    pub fn feel(&mut self, device_force_n: Vector3<f64>) {
        self.device_force_n = if device_force_n.iter().all(|f| f.is_finite()) {
            device_force_n
        } else {
            Vector3::zeros()
        };
    }

    /// The contact force the hand perceives, nN at the tip (springs discounted).
    pub fn felt_contact_nn(&self) -> f64 {
        let springs = -self.position_mm.component_mul(&self.hand.spring_n_per_mm);
        let beyond = self.device_force_n - springs;
        // Contact pushes back, against the press direction.
        -beyond.dot(&self.hand.press_direction_haptic) / self.hand.force_scale_n_per_nn
    }

    /// Moves the stylus up to `now_s` and the script along.
    pub fn advance(&mut self, now_s: f64) {
        let Some(last) = self.last_s.replace(now_s) else {
            self.phase_since_s = now_s;
            return;
        };
        let mut t = last;
        while t < now_s {
            let dt = (now_s - t).min(MAX_STEP_S);
            self.step(dt);
            t += dt;
        }
        self.update_phase(now_s);
    }

    fn hand_target_mm(&self) -> Vector3<f64> {
        let p = &self.params;
        let along = match self.phase {
            Phase::Centre | Phase::Hold | Phase::Rest => 0.0,
            Phase::Approach => p.approach_mm,
            Phase::Press => p.press_mm,
            Phase::Retract => -p.retract_mm,
        };
        self.hand.press_direction_haptic * along
    }

    /// Semi-implicit Euler on m x'' = F_device + k (target - x) - b x'.
    fn step(&mut self, dt: f64) {
        let k_n_per_mm = self.params.hand_stiffness_n_per_mm;
        let m = self.params.stylus_mass_kg;
        // Critically damped grip: b = 2 sqrt(k m), in N s/mm.
        let b_n_s_per_mm = 2.0 * (k_n_per_mm * 1e3 * m).sqrt() * 1e-3;
        let force_n = self.device_force_n + (self.hand_target_mm() - self.position_mm) * k_n_per_mm
            - self.velocity_mm_s * b_n_s_per_mm;
        self.velocity_mm_s += force_n / m * 1e3 * dt;
        self.position_mm += self.velocity_mm_s * dt;
    }

    fn update_phase(&mut self, now_s: f64) {
        let p = &self.params;
        let in_phase = now_s - self.phase_since_s;
        let felt = self.felt_contact_nn();
        let next = match self.phase {
            Phase::Centre if in_phase >= 0.5 => Some(Phase::Approach),
            Phase::Approach if felt >= p.touch_nn => Some(Phase::Press),
            Phase::Press if felt >= p.target_force_nn => Some(Phase::Hold),
            Phase::Hold if in_phase >= p.hold_s => Some(Phase::Retract),
            Phase::Retract if in_phase >= p.retract_s => Some(Phase::Rest),
            Phase::Rest if in_phase >= p.rest_s => {
                self.cycles += 1;
                Some(Phase::Approach)
            }
            _ => None,
        };
        if let Some(phase) = next {
            self.phase = phase;
            self.phase_since_s = now_s;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn operator() -> Operator {
        Operator::new(
            OperatorParams::default(),
            HandModel {
                press_direction_haptic: Vector3::new(0.0, 0.0, -1.0),
                spring_n_per_mm: Vector3::repeat(0.05),
                force_scale_n_per_nn: 2e-4,
            },
        )
    }

    #[test]
    fn approaches_after_centring_and_settles_where_springs_balance() {
        let mut op = operator();
        op.advance(0.0);
        op.advance(0.6);
        assert_eq!(op.phase(), Phase::Approach);
        // With the centring spring rendered, the stylus settles at k_h a / (k_h + k_s).
        for i in 1..=3000 {
            let springs = -op.position_mm() * 0.05;
            op.feel(springs);
            op.advance(0.6 + i as f64 * 1e-3);
        }
        let expected = -15.0 * 0.6 / (0.6 + 0.05);
        assert!(
            (op.position_mm().z - expected).abs() < 0.01,
            "{}",
            op.position_mm()
        );
        assert!(op.felt_contact_nn().abs() < 1.0, "springs are discounted");
    }

    #[test]
    fn felt_force_moves_the_script_through_its_phases() {
        let mut op = operator();
        op.advance(0.0);
        op.advance(0.6);
        let contact =
            |op: &Operator, nn: f64| -op.position_mm() * 0.05 + Vector3::new(0.0, 0.0, nn * 2e-4);
        op.feel(contact(&op, 200.0));
        op.advance(0.601);
        assert_eq!(op.phase(), Phase::Press);
        op.feel(contact(&op, 3100.0));
        op.advance(0.602);
        assert_eq!(op.phase(), Phase::Hold);
        op.advance(2.7);
        assert_eq!(op.phase(), Phase::Retract);
        op.feel(Vector3::zeros());
        op.advance(8.8);
        assert_eq!(op.phase(), Phase::Rest);
        op.advance(9.9);
        assert_eq!(op.phase(), Phase::Approach);
        assert_eq!(op.cycles, 1);
    }
}
