//! Significance indices reproduce the qualitative result of paper Fig. 3.

use cellcal::analysis::significance;

use super::common::tx60;

#[test]
fn paper_figure_3_pattern() {
    let s = significance(&tx60(), 50, 7);
    let get = |n: &str| s.iter().find(|r| r.name == n).expect("param present");
    // alpha6 and theta6 do not affect position (ball on the flange axis)
    assert!(get("alpha6").e_p_mm.abs() < 1e-9);
    assert!(get("theta6").e_p_mm.abs() < 1e-9);
    // d and a do not affect attitude
    for j in 1..=6 {
        for k in ["d", "a"] {
            let r = get(&format!("{k}{j}"));
            assert!(r.e_n.abs() + r.e_o.abs() + r.e_a.abs() < 1e-12, "{k}{j}");
        }
    }
    // lengths move the point by about their perturbation; angles about their lever arm
    assert!((get("d4").e_p_mm - 0.1).abs() < 0.01);
    assert!(get("theta1").e_p_mm > 10.0);
    // theta6 turns n and o but not a; alpha6 does not turn n
    assert!(get("theta6").e_a.abs() < 1e-9 && get("theta6").e_n > 0.05);
    assert!(get("alpha6").e_n.abs() < 1e-9 && get("alpha6").e_o > 0.05);
    // deterministic
    assert_eq!(s, significance(&tx60(), 50, 7));
}
