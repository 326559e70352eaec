use super::*;
use crate::strategy::StrategyKind;

#[test]
fn pareto_front_of_a_hand_made_set() {
    // (cost, error). By hand: (1,9) cheapest; (2,4) and (5,1) trade
    // off; (3,4) is dominated by (2,4) (same error, costlier); (6,1)
    // by (5,1); (4,6) by (2,4); (2,4) twice: equal points are both on
    // the front; NaN never.
    let pts = [
        (1.0, 9.0),
        (2.0, 4.0),
        (3.0, 4.0),
        (5.0, 1.0),
        (6.0, 1.0),
        (4.0, 6.0),
        (2.0, 4.0),
        (f64::NAN, 0.0),
        (0.5, f64::NAN),
    ];
    assert_eq!(
        pareto_front(&pts),
        [true, true, false, true, false, false, true, false, false]
    );
    assert!(pareto_front(&[]).is_empty());
    assert_eq!(pareto_front(&[(3.0, 3.0)]), [true]);
}

#[test]
fn variants_follow_the_config_and_drop_duplicates() {
    let c = SweepConfig {
        // 9216 rays: ×0.25 and ×0.5 both round to θa = 2, θd = 1.
        factors: vec![0.25, 0.5, 1.0, 4.0],
        ..SweepConfig::default()
    };
    let (v, skipped) = c.variants().unwrap();
    assert_eq!(skipped, ["lipac ×0.5"]);
    let t = |name: &str| {
        v.iter()
            .find(|x| x.name == name)
            .and_then(|x| x.lipac.as_ref())
            .map(|l| l.thresholds)
            .unwrap()
    };
    // 4 · 9216 / 2073600 · 1000 = 17.8 → 18; · 100 → 1.78 → 2.
    let t4 = t("lipac ×4");
    assert_eq!(
        (t4.theta_a, t4.theta_d, t4.sigma_a, t4.sigma_o),
        (18, 2, 18, 2)
    );
    let t1 = t("lipac ×1");
    assert_eq!((t1.theta_a, t1.theta_d), (4, 1));
    assert_eq!(
        (t("lipac n_a 1 n_d 15").n_a, t("lipac n_a 4 n_d 30").n_d),
        (1, 30)
    );
    let cells: Vec<f64> = v
        .iter()
        .filter(|x| x.family == Family::CellSize)
        .map(|x| x.lipac.as_ref().unwrap().cell_size)
        .collect();
    assert_eq!(cells, [16.0, 64.0]);
    let bad = SweepConfig {
        factors: vec![0.0],
        ..SweepConfig::default()
    };
    assert!(bad.variants().is_err());
    let bad = SweepConfig {
        baselines: vec![StrategyKind::Lipac],
        ..SweepConfig::default()
    };
    assert!(bad.variants().is_err());
}
