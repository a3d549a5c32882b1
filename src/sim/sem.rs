//! The simulated SEM's view of the lab: for a capture time it reads where the stage is,
//! bends the cantilever with the exact contact model, and describes the frame the
//! scene renderer should draw (magnification from the script, the style's clutter and
//! noise, the substrate closing in under the apex), with the true angle and force.
//! It also renders the calibration frame and clicks on it the way a person would.
use image::GrayImage;
use nalgebra::Vector3;

use super::config::SemParams;
use super::contact::{Bending, Contact};
use crate::hw::frames::FrameTruth;
use crate::model::Cantilever;
use crate::scene::{self, Entry, FrameSpec, ProbeGeometry, Session, Setup, Style};
use crate::vision::{CalibrationConfig, Threshold};

/// The probe as the simulated SEM draws it: the typical pyramid on the configured beam.
pub fn probe_for(cantilever: &Cantilever) -> ProbeGeometry {
    let length_m = cantilever.length_um * 1e-6;
    ProbeGeometry {
        length_um: cantilever.length_um,
        spring_constant_n_per_m: 3.0 * cantilever.flexural_rigidity_n_m2
            / (length_m * length_m * length_m),
        ..ProbeGeometry::typical()
    }
}

/// Where the apex sits in the frame at contact, as fractions of width and height.
const APEX_AT_CONTACT: [f64; 2] = [0.45, 0.55];

#[derive(Debug, Clone)]
pub struct SemScene {
    pub params: SemParams,
    pub setup: Setup,
    pub style: Style,
    pub contact: Contact,
    /// +1 or -1: the sign of the tip angle on screen while pressing.
    pub pressing_sign: f64,
}

impl SemScene {
    pub fn new(params: SemParams, contact: Contact, pressing_sign: f64) -> Self {
        let style = match params.style.as_str() {
            "clean" => Style::Clean,
            "clutter" => Style::Clutter,
            "harsh" => Style::Harsh,
            _ => Style::Noisy,
        };
        let setup = Setup {
            probe: probe_for(&contact.cantilever),
            width: params.width,
            height: params.height,
            entry: Entry::Left,
            base_deg: -18.0,
        };
        SemScene {
            params,
            setup,
            style,
            contact,
            pressing_sign,
        }
    }

    /// The frame captured at `t_s` with the stage at `stage_um`, and its truth.
    pub fn frame(
        &self,
        t_s: f64,
        sequence: u64,
        stage_um: Vector3<f64>,
    ) -> (FrameSpec, FrameTruth) {
        let bending: Bending = self.contact.bending(stage_um);
        let angle_deg = self.pressing_sign * bending.phi0_rad.to_degrees();
        let magnification = self.params.magnification_at(t_s);
        let seed = self
            .params
            .seed
            .wrapping_mul(1_000_003)
            .wrapping_add(sequence);
        let mut spec = self.setup.frame(self.style, angle_deg, magnification, seed);
        // Before contact the probe descends toward its contact point; then the apex stays
        // on the sample and the beam bends.
        let travel_um = stage_um.dot(&self.contact.press_direction);
        let gap_um = (self.contact.sample.contact_at_um - travel_um).max(0.0);
        let ppu = spec.px_per_um();
        let (w, h) = (f64::from(spec.width), f64::from(spec.height));
        let lateral = stage_um - self.contact.press_direction * travel_um;
        spec.apex_px = [
            (APEX_AT_CONTACT[0] * w + lateral.x * ppu).clamp(0.25 * w, 0.75 * w),
            (APEX_AT_CONTACT[1] * h - gap_um * ppu).clamp(0.3 * h, 0.75 * h),
        ];
        spec.substrate_gap_um = gap_um;
        let truth = FrameTruth {
            probe_in_view: true,
            angle_deg,
            force_nn: self.pressing_sign * bending.force_nn,
        };
        (spec, truth)
    }

    /// The calibration frame (undeformed probe) and the clicks a person would make on it.
    pub fn reference(
        &self,
        threshold: Threshold,
        window_deg: f64,
    ) -> (GrayImage, CalibrationConfig) {
        let reference = self.setup.reference(self.params.seed);
        let session = Session {
            reference,
            frames: Vec::new(),
            times_s: Vec::new(),
            threshold,
            window_deg,
            click_seed: self.params.seed ^ 0x5EED,
        };
        let clicks = session.clicks();
        let (image, _) = scene::render(&reference);
        let calibration = CalibrationConfig {
            reference_image: "<simulated SEM reference frame>".into(),
            red: clicks.red,
            blue: clicks.blue,
            green: clicks.green,
        };
        (image, calibration)
    }
}
