//! Protocol files: the built-in paper and blind protocols, defaults,
//! round-trip, assignment tables and error reporting with file, line and
//! field.

use std::collections::HashSet;

use kilotouch_study::protocol::{
    BLIND_TOML, CirclingTask, Condition, PAPER_TOML, Protocol, ProtocolError, Scheme, Task,
};

fn line_of(src: &str, needle: &str) -> usize {
    let off = src.find(needle).expect("needle in source");
    src[..off].matches('\n').count() + 1
}

#[test]
fn paper_protocol_replicates_the_experiment() {
    let p = Protocol::paper().unwrap();
    assert_eq!(p.participants, 8);
    assert_eq!(p.conditions, vec![Condition::V, Condition::P, Condition::D]);
    assert_eq!(p.trials_per_session, 10);
    assert_eq!(p.sessions(), 3);
    assert_eq!(p.total_trials(), 8 * 3 * 10);
    let Task::Circling(t) = &p.task else {
        panic!("paper task must be circling")
    };
    assert_eq!(t.obstacle_radius_um, 5.0); // 10 µm beads
    assert_eq!(t.bead_radius_um, 1.5); // 3 µm bead
    assert_eq!(t.min_contact_fraction, 0.5);
    assert_eq!(p.counterbalance.scheme, Scheme::Williams);
    assert_eq!(
        p,
        Protocol::from_toml_str(PAPER_TOML, "paper.toml").unwrap()
    );
}

#[test]
fn paper_assignment_table() {
    let p = Protocol::paper().unwrap();
    let table = p.assignment().unwrap();
    assert_eq!(table.participants.len(), 8);
    assert_eq!(table.orders.len(), 6);
    assert_eq!(table.seed, Some(p.seeds.study));
    // The six orders are the six permutations of V, P, D.
    let all: HashSet<Vec<Condition>> = table.orders.iter().cloned().collect();
    assert_eq!(all.len(), 6);
    for row in &table.participants {
        let mut s = row.sessions.clone();
        s.sort();
        assert_eq!(s, vec![Condition::V, Condition::P, Condition::D]);
        assert_eq!(row.row, row.participant % 6);
        assert_eq!(row.sessions, table.orders[row.row]);
    }
    assert_eq!(table.participants[0].id, "P01");
    assert_eq!(table.participants[7].id, "P08");
    // 8 = 6 + 2: participants 7 and 8 repeat the orders of 1 and 2.
    assert!(!table.report.balanced);
    let repeated: Vec<Vec<usize>> = table
        .report
        .repeated
        .iter()
        .map(|u| u.participants.clone())
        .collect();
    assert_eq!(repeated, vec![vec![0, 6], vec![1, 7]]);
    assert_eq!(
        table.participants[6].sessions,
        table.participants[0].sessions
    );
    assert_eq!(
        table.participants[7].sessions,
        table.participants[1].sessions
    );
    assert!(table.summary.contains("cannot be fully balanced"));
    // Deterministic from the study seed; another seed may relabel.
    assert_eq!(table, p.assignment().unwrap());
    let mut relabelled = false;
    for seed in 0..20 {
        let mut q = p.clone();
        q.seeds.study = seed;
        let t = q.assignment().unwrap();
        relabelled |= t.participants[0].sessions != table.participants[0].sessions;
    }
    assert!(relabelled, "the study seed never changed the first order");
    // Without the permutation the first order is the Williams row 0 1 2.
    let mut q = p.clone();
    q.counterbalance.permute_labels = false;
    let t = q.assignment().unwrap();
    assert_eq!(t.seed, None);
    assert_eq!(
        t.participants[0].sessions,
        vec![Condition::V, Condition::P, Condition::D]
    );
    let json = serde_json::to_value(&t).unwrap();
    assert_eq!(json["participants"][1]["sessions"][0], "P");
}

#[test]
fn blind_protocol() {
    let p = Protocol::builtin("blind").unwrap();
    assert_eq!(p.participants, 5);
    assert_eq!(p.conditions, vec![Condition::D]);
    let Task::BlindNavigation(t) = &p.task else {
        panic!("blind task expected")
    };
    assert!(t.success_angle_deg > 0.0 && t.success_angle_deg <= 90.0);
    let table = p.assignment().unwrap();
    assert_eq!(table.orders, vec![vec![Condition::D]]);
    assert!(
        table
            .participants
            .iter()
            .all(|r| r.sessions == [Condition::D])
    );
    assert!(table.report.balanced);
    assert_eq!(
        p,
        Protocol::from_toml_str(BLIND_TOML, "blind.toml").unwrap()
    );
    assert!(matches!(
        Protocol::builtin("nope"),
        Err(ProtocolError::UnknownBuiltin(_))
    ));
}

#[test]
fn fixed_scheme_gives_everyone_the_listed_order() {
    let src = PAPER_TOML.replacen("scheme = \"williams\"", "scheme = \"fixed\"", 1);
    let p = Protocol::from_toml_str(&src, "fixed.toml").unwrap();
    assert_eq!(p.counterbalance.scheme, Scheme::Fixed);
    let t = p.assignment().unwrap();
    assert_eq!(t.orders, vec![p.conditions.clone()]);
    assert!(t.participants.iter().all(|r| r.sessions == p.conditions));
    assert_eq!(t.seed, None);
    // Same order for all 8: positions are maximally unbalanced.
    assert!(!t.report.balanced);
    assert_eq!(t.report.position_spread, 8);
    assert_eq!(t.report.repeated[0].count, 8);
}

#[test]
fn defaults_fill_missing_keys() {
    let p = Protocol::from_toml_str(
        "name = \"min\"\nparticipants = 2\n[task.circling]\n",
        "min.toml",
    )
    .unwrap();
    assert_eq!(p.conditions, Condition::ALL.to_vec());
    assert_eq!(p.trials_per_session, 10);
    assert_eq!(p.task, Task::Circling(CirclingTask::default()));
    let Task::Circling(t) = &p.task else { panic!() };
    assert_eq!(
        (
            t.obstacle_radius_um,
            t.bead_radius_um,
            t.min_contact_fraction
        ),
        (5.0, 1.5, 0.5)
    );
    assert_eq!(p.training.practice_trials, 3);
    assert_eq!(p.seeds.study, 0);
    assert!(p.counterbalance.permute_labels);
}

#[test]
fn round_trip_through_toml() {
    for p in [
        Protocol::paper().unwrap(),
        Protocol::builtin("blind").unwrap(),
    ] {
        let text = p.to_toml_string().unwrap();
        let q = Protocol::from_toml_str(&text, "roundtrip.toml").unwrap();
        assert_eq!(p, q, "{text}");
    }
}

/// The paper file with `from` replaced by `to`, and the (expected) error.
fn paper_with(from: &str, to: &str) -> (String, ProtocolError) {
    assert!(PAPER_TOML.contains(from), "{from}");
    let src = PAPER_TOML.replacen(from, to, 1);
    let Err(err) = Protocol::from_toml_str(&src, "study.toml") else {
        panic!("`{to}` was accepted")
    };
    (src, err)
}

fn assert_invalid(from: &str, to: &str, field: &str, needle: &str, message_part: &str) {
    let (src, err) = paper_with(from, to);
    let text = err.to_string();
    let ProtocolError::Invalid { location, invalid } = &err else {
        panic!("expected Invalid, got {err:?}")
    };
    assert_eq!(invalid.field, field, "{text}");
    assert_eq!(location.file, "study.toml");
    assert_eq!(location.line, Some(line_of(&src, needle)), "{text}");
    assert!(text.contains(message_part), "{text}");
    assert!(
        text.starts_with(&format!("study.toml:{}:", line_of(&src, needle))),
        "{text}"
    );
    assert!(text.contains(&format!("field `{field}`")), "{text}");
}

fn assert_parse(from: &str, to: &str, field: Option<&str>, needle: &str, message_part: &str) {
    let (src, err) = paper_with(from, to);
    let text = err.to_string();
    let ProtocolError::Parse {
        location,
        field: f,
        message,
    } = &err
    else {
        panic!("expected Parse, got {err:?}")
    };
    assert_eq!(location.line, Some(line_of(&src, needle)), "{text}");
    assert_eq!(f.as_deref(), field, "{text}");
    assert!(message.contains(message_part), "{text}");
    assert!(text.starts_with("study.toml:"), "{text}");
}

#[test]
fn semantic_errors_name_file_line_and_field() {
    assert_invalid(
        "participants = 8",
        "participants = 0",
        "participants",
        "participants = 0",
        "at least 1",
    );
    assert_invalid(
        "trials_per_session = 10",
        "trials_per_session = 0",
        "trials_per_session",
        "trials_per_session = 0",
        "at least 1",
    );
    assert_invalid(
        "conditions = [\"V\", \"P\", \"D\"]",
        "conditions = [\"V\", \"P\", \"V\"]",
        "conditions[2]",
        "conditions = ",
        "duplicate condition `V`",
    );
    assert_invalid(
        "conditions = [\"V\", \"P\", \"D\"]",
        "conditions = []",
        "conditions",
        "conditions = []",
        "at least one",
    );
    assert_invalid(
        "timeout_s = 120.0",
        "timeout_s = -5.0",
        "task.circling.timeout_s",
        "timeout_s = -5.0",
        "positive",
    );
    assert_invalid(
        "timeout_s = 120.0",
        "timeout_s = nan",
        "task.circling.timeout_s",
        "timeout_s = nan",
        "positive",
    );
    assert_invalid(
        "min_contact_fraction = 0.5",
        "min_contact_fraction = 1.5",
        "task.circling.min_contact_fraction",
        "min_contact_fraction = 1.5",
        "(0, 1]",
    );
    assert_invalid(
        "bead_radius_um = 1.5",
        "bead_radius_um = 0.0",
        "task.circling.bead_radius_um",
        "bead_radius_um = 0.0",
        "positive",
    );
    assert_invalid(
        "contact_gap_um = 0.2",
        "contact_gap_um = -0.1",
        "tolerances.contact_gap_um",
        "contact_gap_um = -0.1",
        "non-negative",
    );
    assert_invalid(
        "name = \"paper-circling\"",
        "name = \"  \"",
        "name",
        "name = \"  \"",
        "empty",
    );
    // The duplicate is pointed at precisely (column of the second "V").
    let (src, err) = paper_with(
        "conditions = [\"V\", \"P\", \"D\"]",
        "conditions = [\"V\", \"P\", \"V\"]",
    );
    let ProtocolError::Invalid { location, .. } = err else {
        panic!()
    };
    let line = src.lines().nth(location.line.unwrap() - 1).unwrap();
    assert_eq!(&line[location.column.unwrap() - 1..], "\"V\"]");
}

/// The refusal of the blind protocol `src`: the error, its field and its line.
fn blind_refusal(src: &str) -> (ProtocolError, String, Option<usize>) {
    let err = Protocol::from_toml_str(src, "blind.toml").expect_err("refused");
    let ProtocolError::Invalid { invalid, location } = &err else {
        panic!("{err:?}")
    };
    let (field, line) = (invalid.field.clone(), location.line);
    (err, field, line)
}

/// The obstacle of a blind trial lies R_o + R_b + start_distance from the
/// start; its centre must be inside the scene's reach even when the
/// movement itself (start_distance + retreat) is short. Found by
/// `loader_props` at 100 000 cases: R_o = 15 µm put the centre at 26.5 µm.
#[test]
fn blind_task_obstacle_centre_fits_the_scene() {
    let src = BLIND_TOML.replacen("obstacle_radius_um = 5.0", "obstacle_radius_um = 15.0", 1);
    let (err, field, line) = blind_refusal(&src);
    assert_eq!(field, "task.blind_navigation.start_distance_um", "{err}");
    assert_eq!(line, Some(line_of(&src, "start_distance_um = ")));
    assert!(err.to_string().contains("26.5 µm"), "{err}");
    // 5 + 1.5 + 13.5 = 20 µm: exactly at the reach, accepted.
    let src = BLIND_TOML.replacen("start_distance_um = 10.0", "start_distance_um = 13.5", 1);
    let src = src.replacen("retreat_distance_um = 3.0", "retreat_distance_um = 1.0", 1);
    Protocol::from_toml_str(&src, "blind.toml").expect("R_o + R_b + start = reach fits");
}

#[test]
fn blind_task_rejects_vision_only() {
    let src = BLIND_TOML.replacen("conditions = [\"D\"]", "conditions = [\"D\", \"V\"]", 1);
    let (_, field, line) = blind_refusal(&src);
    assert_eq!(field, "conditions[1]");
    assert_eq!(line, Some(line_of(&src, "conditions = ")));
    let src = BLIND_TOML.replacen("success_angle_deg = 30.0", "success_angle_deg = 120.0", 1);
    let err = Protocol::from_toml_str(&src, "blind.toml").unwrap_err();
    assert!(
        err.to_string()
            .contains("field `task.blind_navigation.success_angle_deg`"),
        "{err}"
    );
}

#[test]
fn parse_errors_name_file_line_and_field() {
    // Unknown keys (deny_unknown_fields) at the top level and in a table.
    assert_parse(
        "trials_per_session = 10",
        "trials_per_session = 10\ntrials = 3",
        Some("trials"),
        "trials = 3",
        "unknown key `trials`",
    );
    assert_parse(
        "revolutions = 1.0",
        "revolutions = 1.0\nradius_um = 3.0",
        Some("task.circling.radius_um"),
        "radius_um = 3.0",
        "unknown key `radius_um`",
    );
    // Unknown condition code.
    assert_parse(
        "conditions = [\"V\", \"P\", \"D\"]",
        "conditions = [\"V\", \"X\", \"D\"]",
        Some("conditions[1]"),
        "conditions = ",
        "unknown value `X`",
    );
    // Negative count and wrong type.
    assert_parse(
        "participants = 8",
        "participants = -8",
        Some("participants"),
        "participants = -8",
        "",
    );
    assert_parse(
        "timeout_s = 120.0",
        "timeout_s = \"long\"",
        Some("task.circling.timeout_s"),
        "timeout_s = \"long\"",
        "got the text \"long\", expected a number",
    );
    // Unknown task.
    assert_parse(
        "[task.circling]",
        "[task.juggling]",
        Some("task.juggling"),
        "[task.juggling]",
        "unknown value `juggling`",
    );
    // Syntax error.
    let (src, err) = paper_with("participants = 8", "participants = = 8");
    let ProtocolError::Parse { location, .. } = &err else {
        panic!("{err:?}")
    };
    assert_eq!(location.line, Some(line_of(&src, "participants = = 8")));
    // Missing required key.
    let err =
        Protocol::from_toml_str("name = \"x\"\n[task.circling]\n", "missing.toml").unwrap_err();
    assert!(err.to_string().contains("participants"), "{err}");
    let err =
        Protocol::from_toml_str("name = \"x\"\nparticipants = 3\n", "missing.toml").unwrap_err();
    assert!(err.to_string().contains("task"), "{err}");
}

#[test]
fn io_error_names_the_file() {
    let err = Protocol::load(std::path::Path::new("/nonexistent/dir/study.toml")).unwrap_err();
    assert!(matches!(err, ProtocolError::Io { .. }));
    assert!(
        err.to_string().starts_with("/nonexistent/dir/study.toml:"),
        "{err}"
    );
}

#[test]
fn load_reads_the_asset_files() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../assets/protocols");
    let paper = Protocol::load(&dir.join("paper.toml")).unwrap();
    assert_eq!(paper, Protocol::paper().unwrap());
    let blind = Protocol::load(&dir.join("blind.toml")).unwrap();
    assert_eq!(blind, Protocol::builtin("blind").unwrap());
}

#[test]
fn condition_meanings() {
    assert!(!Condition::V.haptic() && !Condition::V.haptuator());
    assert!(Condition::P.pantograph() && !Condition::P.haptuator());
    assert!(Condition::D.pantograph() && Condition::D.haptuator());
    assert_eq!(Condition::D.to_string(), "D");
    assert!(Condition::V.description().contains("vision only"));
}
