//! Unit tests of the command line: the clap definition and its argument rules, exit codes,
//! who may reach `serve`, the token entry `cellcal token` prints, and `--start-deg`.

use std::net::SocketAddr;
use std::path::Path;

use clap::error::ErrorKind;
use clap::{CommandFactory, Parser};

use cellcal::auth::{Role, TokenDigest};
use cellcal::config::{parse_cell_config, ApiSection, ApiToken};

use super::access::{accepted_tokens, check_exposure};
use super::compensate::start;
use super::token::toml_entry;
use super::{input, other};
use crate::Cli;

/// What clap says about `args` (`Ok` when they parse).
fn parse(args: &[&str]) -> Result<(), ErrorKind> {
    let mut all = vec!["cellcal"];
    all.extend_from_slice(args);
    Cli::try_parse_from(all).map(|_| ()).map_err(|e| e.kind())
}

#[test]
fn the_clap_definition_is_consistent() {
    Cli::command().debug_assert();
}

#[test]
fn identify_takes_a_csv_or_a_store_never_both() {
    let csv = [
        "identify", "--robot", "r.toml", "--data", "d.csv", "--model", "op",
    ];
    assert_eq!(parse(&csv), Ok(()));
    assert_eq!(parse(&["identify", "--store", "c.db"]), Ok(()));
    assert_eq!(
        parse(&["identify", "--store", "c.db", "--data", "d.csv"]),
        Err(ErrorKind::ArgumentConflict)
    );
    assert_eq!(
        parse(&["identify", "--robot", "r.toml", "--model", "op"]),
        Err(ErrorKind::MissingRequiredArgument)
    );
}

#[test]
fn identify_parses_axes_and_vectors_at_the_edge() {
    let base = ["identify", "--store", "c.db"];
    for (flag, value, ok) in [
        ("--stage-axis", "-y", true),
        ("--stage-axis", "0.1,-1,0", true),
        ("--stage-axis", "up", false),
        ("--tool-mm", "-1,2,60", true),
        ("--tool-mm", "1,2", false),
        ("--tool-mm", "1,nan,2", false),
        ("--model", "sideways", false),
    ] {
        let mut args = base.to_vec();
        args.extend([flag, value]);
        let got = parse(&args);
        if ok {
            assert_eq!(got, Ok(()), "{flag} {value}");
        } else {
            assert!(
                matches!(
                    got,
                    Err(ErrorKind::ValueValidation | ErrorKind::InvalidValue)
                ),
                "{flag} {value}: {got:?}"
            );
        }
    }
    let mut robust = base.to_vec();
    robust.push("--robust");
    assert_eq!(parse(&robust), Ok(()), "--robust alone is Huber");
}

#[test]
fn run_serve_token_and_compensate_refuse_what_they_do_not_know() {
    assert_eq!(parse(&["run", "--on-fault", "fail"]), Ok(()));
    assert_eq!(
        parse(&["run", "--on-fault", "retry"]),
        Err(ErrorKind::InvalidValue)
    );
    // re-registration and accepted changes only apply to a resumed campaign
    assert_eq!(
        parse(&["run", "--reregister"]),
        Err(ErrorKind::MissingRequiredArgument)
    );
    assert_eq!(
        parse(&[
            "run",
            "--campaign",
            "3",
            "--reregister",
            "--accept-changed-config"
        ]),
        Ok(())
    );
    assert_eq!(
        parse(&["serve", "--log-format", "xml"]),
        Err(ErrorKind::InvalidValue)
    );
    assert_eq!(
        parse(&["token", "--name", "a", "--role", "admin"]),
        Err(ErrorKind::InvalidValue)
    );
    let comp = [
        "compensate",
        "--robot",
        "r",
        "--identified",
        "i",
        "--out",
        "o",
    ];
    assert_eq!(parse(&comp), Err(ErrorKind::MissingRequiredArgument));
    let mut both = comp.to_vec();
    both.extend(["--targets", "t.csv", "--joints", "j.csv"]);
    assert_eq!(parse(&both), Err(ErrorKind::ArgumentConflict));
    let mut one = comp.to_vec();
    one.extend(["--joints", "j.csv", "--start-deg", "-10,30,90,0,45,0"]);
    assert_eq!(parse(&one), Ok(()));
}

#[test]
fn bad_input_exits_2_and_anything_else_1() {
    assert_eq!(input(anyhow::anyhow!("x")).0, 2);
    assert_eq!(other(anyhow::anyhow!("x")).0, 1);
}

#[test]
fn start_degrees_are_checked_and_converted_to_radians() {
    let q = start(None, 6).ok().expect("the default for six joints");
    assert_eq!(q[1], 30f64.to_radians());
    assert_eq!(start(None, 7).expect_err("no default").0, 2);
    let q = start(Some(" 90, -45 "), 2).ok().expect("two joints");
    assert_eq!(q, vec![90f64.to_radians(), (-45f64).to_radians()]);
    for bad in ["90,inf", "90,x", "90"] {
        let e = start(Some(bad), 2).expect_err("refused");
        assert_eq!(e.0, 2, "{bad}");
    }
}

fn addr(s: &str) -> SocketAddr {
    s.parse().expect("address")
}

#[test]
fn serve_is_exposed_beyond_loopback_only_with_configured_tokens() {
    let open = ApiSection::default();
    assert!(check_exposure(addr("127.0.0.1:8080"), &open).is_ok());
    assert!(check_exposure(addr("[::1]:8080"), &open).is_ok());
    let e = check_exposure(addr("0.0.0.0:8080"), &open).expect_err("refused");
    assert_eq!(e.0, 2);
    assert!(e.1.to_string().contains("--listen 0.0.0.0:8080"), "{}", e.1);
    let with_token = ApiSection {
        tokens: vec![ApiToken {
            name: "alice".into(),
            role: Role::Operator,
            digest: TokenDigest::of_token("secret"),
        }],
        ..ApiSection::default()
    };
    assert!(check_exposure(addr("0.0.0.0:8080"), &with_token).is_ok());

    // configured tokens are taken as they are; none: one new operator token, shown once
    let (table, shown) = accepted_tokens(&with_token).ok().expect("tokens");
    assert_eq!(shown, None);
    let alice = table.authenticate("secret").expect("alice");
    assert_eq!((alice.name.as_str(), alice.role), ("alice", Role::Operator));
    let (table, shown) = accepted_tokens(&open).ok().expect("one-time");
    let token = shown.expect("shown once");
    assert_eq!(token.len(), 64);
    let p = table.authenticate(&token).expect("accepted");
    assert_eq!(p.role, Role::Operator);
    assert!(table.authenticate("secret").is_none());
}

#[test]
fn the_printed_token_entry_is_read_back_by_the_configuration_parser() {
    let digest = TokenDigest::of_token("t0k3n");
    let name = "o\"brien \\ night shift";
    let entry = toml_entry(name, Role::Technician, &digest);
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/cell.sim.toml");
    let text = std::fs::read_to_string(&path).expect("cell.sim.toml");
    // the entry goes at the end of the file, as the command says to paste it
    let cfg = parse_cell_config(&format!("{text}\n{entry}"), &path).expect("config");
    assert_eq!(
        cfg.api.tokens,
        [ApiToken {
            name: name.into(),
            role: Role::Technician,
            digest,
        }]
    );
}
