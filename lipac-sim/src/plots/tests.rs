use super::*;

fn labels(svg: &str) -> Vec<String> {
    svg.split("<text")
        .skip(1)
        .filter_map(|t| t.split_once('>'))
        .filter_map(|(_, rest)| rest.split_once("</text>"))
        .map(|(s, _)| s.trim().to_string())
        .collect()
}

#[test]
fn axes_pick_log_only_over_decades() {
    let a = Axis::auto("e", &[0.0, 0.002, 0.5]);
    assert!(a.log);
    assert_eq!(a.range, 0.001..1.0);
    assert!(a.label.contains("0 at the floor"));
    let b = Axis::auto("m", &[3.0, 40.0]);
    assert!(!b.log);
    assert_eq!(b.range, 0.0..50.0);
    assert_eq!(nice_max(53.8), 100.0);
    assert_eq!(nice_max(2.0), 2.0);
    assert_eq!(nice_max(0.0), 1.0);
}

#[test]
fn svg_has_round_ticks_and_one_legend_entry_per_series() {
    let mut p = Plot::new(
        "T",
        Axis::fixed("frame", 0.0..269.0),
        Axis::auto("err", &[0.001, 0.9]),
    );
    p.series
        .push(Series::line("lipac", 0, vec![(0.0, 0.5), (269.0, 0.001)]));
    p.series.push(Series::line(
        "lipac-latency",
        1,
        vec![(0.0, 0.4), (269.0, 0.002)],
    ));
    let svg = p.svg().unwrap();
    let l = labels(&svg);
    assert_eq!(l.iter().filter(|s| *s == "lipac").count(), 1, "{l:?}");
    assert_eq!(l.iter().filter(|s| *s == "lipac-latency").count(), 1);
    for tick in ["0", "50", "100", "250", "0.001", "0.01", "0.1", "1"] {
        assert!(l.iter().any(|s| s == tick), "{tick} in {l:?}");
    }
    // Every numeric label is round: at most two significant digits here.
    for s in l.iter().filter(|s| s.parse::<f64>().is_ok()) {
        let digits = s.trim_start_matches(['0', '.']).replace('.', "");
        assert!(digits.trim_end_matches('0').len() <= 2, "{s}");
    }
    // The legend entries stack in the panel right of the chart.
    let ys: Vec<&str> = svg
        .split("<text")
        .filter(|t| t.contains("\nlipac"))
        .filter_map(|t| t.split("y=\"").nth(1)?.split('"').next())
        .collect();
    assert_eq!(ys.len(), 2);
    assert_ne!(ys[0], ys[1]);
}

#[test]
fn labels_of_coincident_points_do_not_overlap() {
    let mut p = Plot::new(
        "T",
        Axis::fixed("x", 0.0..10.0),
        Axis::fixed("y", 0.0..10.0),
    );
    p.series.push(Series {
        name: None,
        color: Color::Palette(0),
        shape: Shape::Labels(vec![
            (5.0, 5.0, "first".into()),
            (5.0, 5.0, "second".into()),
            (5.0, 5.0, "third".into()),
        ]),
    });
    let svg = p.svg().unwrap();
    let spot = |name: &str| -> (String, String) {
        let t = svg
            .split("<text")
            .find(|t| t.contains(&format!("\n{name}\n")))
            .unwrap();
        let attr = |a: &str| {
            t.split(&format!(" {a}=\""))
                .nth(1)
                .unwrap()
                .split('"')
                .next()
                .unwrap()
                .to_string()
        };
        (attr("x"), attr("y"))
    };
    let (a, b, c) = (spot("first"), spot("second"), spot("third"));
    assert!(a != b && b != c && a != c, "{a:?} {b:?} {c:?}");
}

#[test]
fn empty_ranges_are_errors() {
    let p = Plot::new("T", Axis::fixed("x", 1.0..1.0), Axis::fixed("y", 0.0..1.0));
    assert!(p.svg().is_err());
}
