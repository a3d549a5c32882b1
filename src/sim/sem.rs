//! The simulated SEM's view of the lab: for a capture time it reads where the stage is,
//! bends the cantilever with the exact contact model, and describes the frame the
//! scene renderer should draw (magnification from the script, the style's clutter and
//! noise, the substrate closing in under the apex), with the true angle and force.
//! It also renders the calibration frame and clicks on it the way a person would.
use image::GrayImage;
use nalgebra::Vector3;

use super::config::{SemParams, SimProbe};
use super::contact::{Bending, Contact};
use crate::hw::frames::{FrameTruth, MAX_TRUTHS, NO_TRUTH};
use crate::model::Cantilever;
use crate::scene::{
    self, tool_clicks, Entry, FrameSpec, Others, Placement, ProbeGeometry, Session, Setup, Style,
    ToolGeometry, MAX_OTHER_PROBES,
};
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

/// Where a lone probe's apex sits in the frame at contact, as fractions of width and
/// height.
const APEX_AT_CONTACT: [f64; 2] = [0.45, 0.55];

#[derive(Debug, Clone)]
pub struct SemScene {
    pub params: SemParams,
    pub style: Style,
    /// The probes in view, in the probes' order (at least one).
    pub probes: Vec<ProbeView>,
}

/// One probe as the simulated SEM shows it.
#[derive(Debug, Clone)]
pub struct ProbeView {
    pub setup: Setup,
    pub contact: Contact,
    /// +1 or -1: the sign of the tip angle on screen while pressing.
    pub pressing_sign: f64,
    /// Where it is in view.
    pub place: SimProbe,
}

impl ProbeView {
    /// `contact`'s cantilever, pressing with tip angles of `pressing_sign`, placed at
    /// `place` in a view of `params`.
    pub fn new(params: &SemParams, contact: Contact, pressing_sign: f64, place: SimProbe) -> Self {
        ProbeView {
            setup: Setup {
                probe: probe_for(&contact.cantilever),
                width: params.width,
                height: params.height,
                entry: place.entry,
                base_deg: match place.entry {
                    Entry::Left => BASE_DEG,
                    Entry::Right => -BASE_DEG,
                },
            },
            contact,
            pressing_sign,
            place,
        }
    }

    /// The rigid tool drawn in the cantilever's stead, if it is one.
    fn tool(&self) -> Option<ToolGeometry> {
        self.place.tool.map(ToolGeometry::typical)
    }

    /// Where it stands at rest in a `width` x `height` view, unbent: the reference's
    /// placement.
    fn at_rest(&self, width: f64, height: f64) -> Placement {
        Placement {
            probe: self.setup.probe,
            entry: self.setup.entry,
            base_deg: self.setup.base_deg,
            angle_deg: 0.0,
            apex_px: [
                self.place.apex_at[0] * width,
                self.place.apex_at[1] * height,
            ],
            blank: false,
            tool: self.tool(),
        }
    }

    /// Its pose and truth with its positioner at `stage_um`, in a view of `spec`'s size
    /// and magnification, and the gap from its apex to the sample.
    fn placed(&self, spec: &FrameSpec, stage_um: Vector3<f64>) -> (Placement, FrameTruth, f64) {
        if self.place.tool.is_some() {
            return self.tool_placed(spec, stage_um);
        }
        let bending: Bending = self.contact.bending(stage_um);
        let angle_deg = self.pressing_sign * bending.phi0_rad.to_degrees();
        // Before contact the probe descends toward its contact point; then the apex stays
        // on the sample and the beam bends.
        let travel_um = stage_um.dot(&self.contact.press_direction);
        let gap_um = (self.contact.sample.contact_at_um - travel_um).max(0.0);
        let ppu = spec.px_per_um();
        let (w, h) = (f64::from(spec.width), f64::from(spec.height));
        let lateral = stage_um - self.contact.press_direction * travel_um;
        let [ax, ay] = self.place.apex_at;
        // The apex may wander further toward the beam's far end than back over it.
        let (left, right) = match self.place.entry {
            Entry::Left => (0.2, 0.3),
            Entry::Right => (0.3, 0.2),
        };
        let place = Placement {
            probe: self.setup.probe,
            entry: self.setup.entry,
            base_deg: self.setup.base_deg,
            angle_deg,
            apex_px: [
                (ax * w + lateral.x * ppu).clamp((ax - left) * w, (ax + right) * w),
                (ay * h - gap_um * ppu).clamp((ay - 0.25) * h, (ay + 0.2) * h),
            ],
            tool: None,
            blank: false,
        };
        let truth = FrameTruth {
            probe_in_view: true,
            angle_deg,
            force_nn: Some(self.pressing_sign * bending.force_nn),
        };
        (place, truth, gap_um)
    }

    /// A rigid tool's pose and truth: it hangs free, unbent, its tip where `apex_at`
    /// puts it when the positioner is at its start, moved on screen as the positioner
    /// moves from there (pressing moves it down), within the view as a cantilever's.
    fn tool_placed(
        &self,
        spec: &FrameSpec,
        stage_um: Vector3<f64>,
    ) -> (Placement, FrameTruth, f64) {
        let (w, h) = (f64::from(spec.width), f64::from(spec.height));
        let press = self.contact.press_direction;
        let moved_um = stage_um - press * self.place.start_um;
        let travel_um = moved_um.dot(&press);
        let lateral_x_um = (moved_um - press * travel_um).x;
        let ppu = spec.px_per_um();
        let [ax, ay] = self.place.apex_at;
        let mut place = self.at_rest(w, h);
        place.apex_px = [
            (ax * w + lateral_x_um * ppu).clamp((ax - 0.25) * w, (ax + 0.25) * w),
            (ay * h + travel_um * ppu).clamp((ay - 0.25) * h, (ay + 0.2) * h),
        ];
        let truth = FrameTruth {
            probe_in_view: true,
            angle_deg: 0.0,
            force_nn: None,
        };
        (place, truth, f64::INFINITY)
    }
}

/// The beam's tilt on screen, degrees (mirrored for a probe entering from the right).
const BASE_DEG: f64 = -18.0;

impl SemScene {
    /// One probe in view, where a lone probe sits.
    pub fn new(params: SemParams, contact: Contact, pressing_sign: f64) -> Self {
        let place = SimProbe {
            entry: Entry::Left,
            apex_at: APEX_AT_CONTACT,
            start_um: 0.0,
            tool: None,
        };
        let probe = ProbeView::new(&params, contact, pressing_sign, place);
        SemScene::several(params, vec![probe])
    }

    /// `probes` in one view (at least one; the first is the frame's own probe).
    pub fn several(params: SemParams, probes: Vec<ProbeView>) -> Self {
        assert!(
            (1..=MAX_TRUTHS).contains(&probes.len()),
            "a view of 1 to {MAX_TRUTHS} probes"
        );
        let style = match params.style.as_str() {
            "clean" => Style::Clean,
            "clutter" => Style::Clutter,
            "harsh" => Style::Harsh,
            _ => Style::Noisy,
        };
        SemScene {
            params,
            style,
            probes,
        }
    }

    /// The frame captured at `t_s` with the first probe's positioner at `stage_um` (the
    /// others at rest), and that probe's truth.
    pub fn frame(
        &self,
        t_s: f64,
        sequence: u64,
        stage_um: Vector3<f64>,
    ) -> (FrameSpec, FrameTruth) {
        let (spec, truths) = self.view(t_s, sequence, &[stage_um]);
        let truth = truths[0].unwrap_or(FrameTruth {
            probe_in_view: false,
            angle_deg: 0.0,
            force_nn: None,
        });
        (spec, truth)
    }

    /// The frame captured at `t_s` with each probe's positioner at `stages_um` (in the
    /// probes' order; a probe without one is at rest), and each probe's truth.
    pub fn view(
        &self,
        t_s: f64,
        sequence: u64,
        stages_um: &[Vector3<f64>],
    ) -> (FrameSpec, [Option<FrameTruth>; MAX_TRUTHS]) {
        let magnification = self.params.magnification_at(t_s);
        let seed = self
            .params
            .seed
            .wrapping_mul(1_000_003)
            .wrapping_add(sequence);
        let first = &self.probes[0];
        let mut spec = first.setup.frame(self.style, 0.0, magnification, seed);
        let mut truths = NO_TRUTH;
        let (own, _, _) = first.placed(&spec, Vector3::zeros());
        let mut others = [own; MAX_OTHER_PROBES];
        for (k, probe) in self.probes.iter().enumerate().take(MAX_TRUTHS) {
            let stage_um = stages_um.get(k).copied().unwrap_or_default();
            let (place, truth, gap_um) = probe.placed(&spec, stage_um);
            truths[k] = Some(truth);
            match k {
                0 => {
                    spec = FrameSpec {
                        substrate_gap_um: gap_um,
                        ..spec.placing(place)
                    }
                }
                k => others[k - 1] = place,
            }
        }
        if self.probes.len() > 1 {
            // The sample's edge would run under the first probe only.
            spec.look.substrate = None;
            spec.others = Others::of(&others[..self.probes.len() - 1]);
        }
        (spec, truths)
    }

    /// The calibration frame (undeformed probe) and the clicks a person would make on it.
    pub fn reference(
        &self,
        threshold: Threshold,
        window_deg: f64,
    ) -> (GrayImage, CalibrationConfig) {
        let (image, mut clicks) = self.references(threshold, window_deg);
        (image, clicks.swap_remove(0))
    }

    /// The calibration frame (every probe undeformed) and the clicks a person would make
    /// on each probe, in the probes' order.
    pub fn references(
        &self,
        threshold: Threshold,
        window_deg: f64,
    ) -> (GrayImage, Vec<CalibrationConfig>) {
        let mut reference = self.probes[0].setup.reference(self.params.seed);
        if self.probes.len() > 1 {
            // Every probe at rest where it stands in the run's first frames.
            let (w, h) = (f64::from(reference.width), f64::from(reference.height));
            reference.magnification = self.params.magnification_at(0.0);
            let others: Vec<Placement> = self.probes[1..].iter().map(|p| p.at_rest(w, h)).collect();
            reference = FrameSpec {
                others: Others::of(&others),
                ..reference.placing(self.probes[0].at_rest(w, h))
            };
            reference.look.particles = 0;
        }
        let session = Session {
            reference,
            frames: Vec::new(),
            times_s: Vec::new(),
            threshold,
            window_deg,
            click_seed: self.params.seed ^ 0x5EED,
        };
        let (image, _) = scene::render(&reference);
        let name = "<simulated SEM reference frame>";
        let clicks = self
            .probes
            .iter()
            .enumerate()
            .map(|(k, probe)| match probe.place.tool {
                Some(kind) => CalibrationConfig {
                    reference_image: name.into(),
                    edges: reference
                        .nth_probe(k)
                        .map_or(Vec::new(), |own| tool_clicks(&own)),
                    apex: Some(kind.apex_edges().map(String::from)),
                },
                None => {
                    let clicks = session.clicks_of(k);
                    CalibrationConfig::pyramid(name.into(), clicks.red, clicks.blue, clicks.green)
                }
            })
            .collect();
        (image, clicks)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::ToolKind;
    use crate::sim::contact::SampleParams;

    /// A cantilever on the left and a needle on the right, as config/sim-needle.toml.
    fn lever_and_needle() -> SemScene {
        let params = SemParams::default();
        let ei = Cantilever::rigidity_from_spring_constant(0.06, 434.675);
        let contact = Contact {
            sample: SampleParams::default(),
            cantilever: Cantilever::new(434.675, ei),
            press_direction: Vector3::new(0.0, 0.0, -1.0),
        };
        let place = |entry, apex_at, tool| SimProbe {
            entry,
            apex_at,
            start_um: 0.0,
            tool,
        };
        let lever = ProbeView::new(
            &params,
            contact.clone(),
            1.0,
            place(Entry::Left, [0.3, 0.45], None),
        );
        let needle = ProbeView::new(
            &params,
            contact,
            -1.0,
            place(Entry::Right, [0.65, 0.4], Some(ToolKind::Needle)),
        );
        SemScene::several(params, vec![lever, needle])
    }

    #[test]
    fn a_tool_hangs_unbent_where_its_positioner_puts_it() {
        let scene = lever_and_needle();
        let pressed = Vector3::new(0.0, 0.0, -40.0);
        let (spec, truths) = scene.view(1.0, 7, &[pressed, Vector3::zeros()]);
        let needle = truths[1].expect("the needle's truth");
        assert_eq!((needle.angle_deg, needle.force_nn), (0.0, None));
        assert!(truths[0].and_then(|t| t.force_nn).is_some_and(|f| f != 0.0));
        let drawn = spec.others.iter().next().expect("the needle is drawn");
        assert_eq!(drawn.tool, Some(ToolGeometry::typical(ToolKind::Needle)));
        let (w, h) = (f64::from(spec.width), f64::from(spec.height));
        assert_eq!(drawn.apex_px, [0.65 * w, 0.4 * h]);
        // Its own positioner moved 5 um along the press direction: 5 um down on screen.
        let (spec, _) = scene.view(1.0, 7, &[pressed, Vector3::new(0.0, 0.0, -5.0)]);
        let moved = spec.others.iter().next().expect("drawn").apex_px;
        assert!(
            (moved[1] - 0.4 * h - 5.0 * spec.px_per_um()).abs() < 1e-9,
            "{moved:?}"
        );
    }

    #[test]
    fn a_tool_is_clicked_on_its_named_edges() {
        let (_, clicks) = lever_and_needle().references(Threshold::Otsu, 20.0);
        assert_eq!(clicks[0].apex, None, "the cantilever's pyramid");
        assert_eq!(
            clicks[1].apex,
            Some(["upper".to_string(), "end".to_string()])
        );
        let names: Vec<&str> = clicks[1].edges.iter().map(|(n, _)| n.as_str()).collect();
        assert_eq!(names, ["upper", "lower", "end"]);
    }
}
