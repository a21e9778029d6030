//! Unit tests of compensation: the CSV tables (columns by name, ids, degrees, bad cells named,
//! the output format) and the [`Compensator`]'s refusals and its identity case.

use nalgebra::Vector3;

use super::table::{parse_joints, parse_targets, write_joints};
use super::{CompensateError, Compensated, Compensator, MAX_LENGTH_CHANGE_MM};
use crate::dataset::CsvError;
use crate::model::{IkError, ParamKind};

#[test]
fn targets_are_found_by_column_name_in_any_order_with_comments_quotes_and_ids() {
    let text =
        "# targets\n\n Z_MM , \"id\", x_mm,y_mm, note\n1.5,\"a\",10,20,x\n\n# gap\n3,b,4,5,y\n";
    let rows = parse_targets(text).expect("targets");
    assert_eq!(rows.len(), 2);
    assert_eq!((rows[0].id.as_str(), rows[0].line), ("a", 4));
    assert_eq!(rows[0].value.position_mm, Vector3::new(10.0, 20.0, 1.5));
    assert_eq!(rows[0].value.rotation, None);
    assert_eq!((rows[1].id.as_str(), rows[1].line), ("b", 7));

    // no id column: the rows are numbered; a rotation vector in degrees
    let rows = parse_targets("x_mm,y_mm,z_mm,rx_deg,ry_deg,rz_deg\n0,0,0,0,0,90\n").expect("rot");
    assert_eq!(rows[0].id, "1");
    let r = rows[0].value.rotation.expect("rotation");
    assert!((r * Vector3::x() - Vector3::y()).norm() < 1e-12);
}

#[test]
fn bad_target_files_are_refused_naming_the_line_and_column() {
    assert!(matches!(parse_targets(""), Err(CsvError::Empty)));
    assert!(matches!(
        parse_targets("x_mm,y_mm,z_mm\n"),
        Err(CsvError::NoRows)
    ));
    assert!(matches!(
        parse_targets("x_mm,y_mm\n1,2\n"),
        Err(CsvError::MissingColumn(c)) if c == "z_mm"
    ));
    assert!(matches!(
        parse_targets("x_mm,x_mm,y_mm,z_mm\n1,1,2,3\n"),
        Err(CsvError::DuplicateColumn(c)) if c == "x_mm"
    ));
    // all three rotation columns or none
    assert!(matches!(
        parse_targets("x_mm,y_mm,z_mm,rx_deg\n1,2,3,4\n"),
        Err(CsvError::MissingColumn(c)) if c == "ry_deg"
    ));
    assert!(matches!(
        parse_targets("x_mm,y_mm,z_mm\n1,2\n"),
        Err(CsvError::Malformed { line: 2, .. })
    ));
    assert!(matches!(
        parse_targets("x_mm,y_mm,z_mm\n1,2,3\n1,two,3\n"),
        Err(CsvError::NotNumeric { line: 3, column, value }) if column == "y_mm" && value == "two"
    ));
    assert!(matches!(
        parse_targets("x_mm,y_mm,z_mm\n1,2,NaN\n"),
        Err(CsvError::NotFinite { line: 2, column, .. }) if column == "z_mm"
    ));
}

#[test]
fn program_joints_are_rad_or_degrees_never_both_and_every_joint_is_needed() {
    let rows = parse_joints("q1,q2\n0.5,-1\n", 2).expect("rad");
    assert_eq!(rows[0].value, vec![0.5, -1.0]);
    let rows = parse_joints("id,q2_deg,q1_deg\np,90,180\n", 2).expect("deg");
    assert_eq!(rows[0].id, "p");
    assert_eq!(rows[0].value, vec![180f64.to_radians(), 90f64.to_radians()]);
    assert!(matches!(
        parse_joints("q1,q1_deg,q2,q2_deg\n1,1,1,1\n", 2),
        Err(CsvError::Malformed { line: 1, .. })
    ));
    assert!(matches!(
        parse_joints("q1\n1\n", 2),
        Err(CsvError::MissingColumn(c)) if c == "q2"
    ));
    assert!(matches!(
        parse_joints("x\n1\n", 2),
        Err(CsvError::MissingColumn(c)) if c == "q1"
    ));
}

#[test]
fn the_joint_file_has_round_trip_joints_quoted_ids_and_the_binding_limits() {
    let rows = [
        Compensated {
            q: vec![0.1, -0.25],
            nominal_q: vec![0.0, 0.0],
            reachable: true,
            residual_mm: 1e-7,
            residual_rad: 0.0,
            at_limit: vec![],
        },
        Compensated {
            q: vec![1.0 / 3.0, 2.0],
            nominal_q: vec![0.0, 0.0],
            reachable: false,
            residual_mm: 1.25,
            residual_rad: 1f64.to_radians(),
            at_limit: vec![1, 2],
        },
    ];
    let out = write_joints(&["a".into(), "b,\"c\"".into()], &rows, 2);
    let lines: Vec<&str> = out.lines().collect();
    assert_eq!(
        lines[0],
        "id,q1,q2,reachable,residual_mm,residual_deg,at_limit,q1_deg,q2_deg"
    );
    assert_eq!(
        lines[1],
        "a,0.1,-0.25,true,0.000000,0.000000,,5.729578,-14.323945"
    );
    assert_eq!(
        lines[2],
        "\"b,\"\"c\"\"\",0.3333333333333333,2.0,false,1.250000,1.000000,q1 q2,19.098593,114.591559"
    );
    // the joints read back bit for bit
    let q: f64 = lines[2]
        .split(',')
        .nth(2)
        .expect("q1")
        .parse()
        .expect("f64");
    assert_eq!(q, 1.0 / 3.0);
}

#[test]
fn a_model_that_is_not_a_calibration_of_the_robot_is_refused_naming_the_parameter() {
    let nominal = crate::model::tx60();
    let mut far = nominal.clone();
    *far.joints[2].get_mut(ParamKind::D) += MAX_LENGTH_CHANGE_MM + 5.0;
    match Compensator::new(&nominal, &far) {
        Err(CompensateError::NotACalibration { name, .. }) => assert_eq!(name, "d3"),
        other => panic!("{other:?}"),
    }
    let mut turned = nominal.clone();
    *turned.joints[1].get_mut(ParamKind::Alpha) += 0.2;
    match Compensator::new(&nominal, &turned) {
        Err(CompensateError::NotACalibration { name, limit, .. }) => {
            assert_eq!((name.as_str(), limit.as_str()), ("alpha2", "10°"));
        }
        other => panic!("{other:?}"),
    }
    let mut short = nominal.clone();
    short.joints.pop();
    short.limits.pop();
    assert!(matches!(
        Compensator::new(&nominal, &short),
        Err(CompensateError::DofMismatch {
            nominal: 6,
            identified: 5
        })
    ));
}

#[test]
fn compensating_the_nominal_robot_changes_nothing_and_bad_joints_are_refused() {
    let nominal = crate::model::tx60();
    let c = Compensator::new(&nominal, &nominal).expect("same robot");
    let q = [0.3, -0.4, 1.6, 0.2, 0.7, -0.5];
    let out = c.program_point(&q).expect("program point");
    assert!(out.reachable);
    assert!(out.residual_mm < 1e-6 && out.residual_rad < 1e-9, "{out:?}");
    for (a, b) in out.q.iter().zip(q) {
        assert!((a - b).abs() < 1e-9, "{:?}", out.q);
    }
    assert!(matches!(
        c.program_point(&q[..5]),
        Err(CompensateError::Joints(IkError::DofMismatch {
            expected: 6,
            got: 5
        }))
    ));
    assert!(matches!(
        c.program_point(&[0.0, f64::NAN, 0.0, 0.0, 0.0, 0.0]),
        Err(CompensateError::Joints(IkError::NotFinite))
    ));
}

#[test]
fn an_identified_model_with_a_compliance_needs_its_masses_and_harmonics_stay_small() {
    use crate::model::{Mass, RobotModel, TermKind};
    let nominal = RobotModel {
        masses: Vec::new(),
        ..crate::model::tx60()
    };
    let mut compliant = nominal.clone();
    *compliant.term_mut(1, TermKind::Compliance) = 2e-6;
    *compliant.term_mut(2, TermKind::Compliance) = 1e-6;
    assert_eq!(
        Compensator::new(&nominal, &compliant)
            .unwrap_err()
            .to_string(),
        "the identified model has a compliance on joint 2, 3 but no [[masses]]: the gravity \
         torques it was identified with are unknown, so compensation would leave the compliance \
         out (give the masses the identification used)"
    );
    compliant.masses.push(Mass {
        frame: 3,
        at: nalgebra::Vector3::new(100.0, 0.0, 50.0),
        kg: 10.0,
    });
    let c = Compensator::new(&nominal, &compliant).expect("with its masses");
    assert_eq!(c.identified().terms, compliant.terms);
    let mut wobbly = nominal.clone();
    *wobbly.term_mut(3, TermKind::Sin2Q) = 0.25;
    match Compensator::new(&nominal, &wobbly) {
        Err(CompensateError::NotACalibration { name, limit, .. }) => {
            assert_eq!((name.as_str(), limit.as_str()), ("sin_2q4", "10°"));
        }
        other => panic!("{other:?}"),
    }
    // the controller's model has no terms, even when its file gives some
    let c = Compensator::new(&compliant, &compliant).expect("same robot");
    assert!(!c.nominal().has_terms() && c.identified().has_terms());
}
