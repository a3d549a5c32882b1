//! Criterion benches of the cantilever model: the start-up table build, the lookups the
//! tracker makes per frame (angle -> elastica, angle -> load, load -> angle), and the
//! exact closed form and inverse for comparison. `cargo bench --bench model`.
use std::hint::black_box;

use criterion::{criterion_group, criterion_main, Criterion};
use nanoforce::model::{exact, phi0_from_alpha, Cantilever, ModelTable};

/// How many inputs each bench cycles through (a power of two: the index is a mask).
const INPUTS: usize = 1024;

/// Angles spread over the range so the lookups visit every piece of the table.
fn angles_deg() -> Vec<f64> {
    (0..INPUTS)
        .map(|i| -89.0 + 178.0 * ((i * 617) % 1024) as f64 / 1023.0)
        .collect()
}

fn table(c: &mut Criterion) {
    c.bench_function("table_build", |b| b.iter(|| black_box(ModelTable::build())));

    let table = ModelTable::global();
    let angles = angles_deg();
    let alphas: Vec<f64> = angles.iter().map(|&a| table.alpha_deg(a).value).collect();
    let mut i = 0;
    let mut next = |values: &[f64]| {
        i = (i + 1) & (INPUTS - 1);
        black_box(values[i])
    };
    c.bench_function("lookup_elastica_deg", |b| {
        b.iter(|| table.elastica_deg(next(&angles)))
    });
    c.bench_function("lookup_alpha_deg", |b| {
        b.iter(|| table.alpha_deg(next(&angles)))
    });
    c.bench_function("lookup_angle_deg_from_alpha", |b| {
        b.iter(|| table.angle_deg_from_alpha(next(&alphas)))
    });
    let cantilever = Cantilever::new(
        434.675,
        Cantilever::rigidity_from_spring_constant(0.06, 434.675),
    );
    c.bench_function("cantilever_force_nn", |b| {
        b.iter(|| cantilever.force_nn(next(&angles)))
    });
}

fn closed_form(c: &mut Criterion) {
    let angles = angles_deg();
    let alphas: Vec<f64> = angles
        .iter()
        .map(|&a| exact(a.to_radians()).map_or(0.0, |e| e.alpha))
        .collect();
    let mut i = 0;
    let mut next = |values: &[f64]| {
        i = (i + 1) & (INPUTS - 1);
        black_box(values[i])
    };
    c.bench_function("exact", |b| b.iter(|| exact(next(&angles).to_radians())));
    c.bench_function("exact_phi0_from_alpha", |b| {
        b.iter(|| phi0_from_alpha(next(&alphas)))
    });
}

criterion_group!(benches, table, closed_form);
criterion_main!(benches);
