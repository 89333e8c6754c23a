//! Unity's 95 humanoid muscles: order, names and default ranges (`HumanTrait.MuscleName`,
//! `GetMuscleDefaultMin/Max`), the column order of every motion.csv.
//!
//! A muscle value m ∈ [−1, 1] is an angle away from the bone's muscle-zero orientation:
//! m·max degrees for m ≥ 0 and m·(−min) for m < 0. Names read "negative-positive": for
//! "Arm Down-Up" −1 is down and +1 up, for "Arm Front-Back" −1 is forward and +1 back, for
//! "Turn Left-Right" −1 turns to the person's own left, for "In-Out" +1 is outward
//! (abduction, external rotation), "Stretch"/"Stretched" +1 is straight.

/// Number of muscles (values per motion frame).
pub const MUSCLES: usize = 95;

/// `HumanTrait.MuscleName`, in order.
pub const MUSCLE_NAMES: [&str; MUSCLES] = [
    "Spine Front-Back",
    "Spine Left-Right",
    "Spine Twist Left-Right",
    "Chest Front-Back",
    "Chest Left-Right",
    "Chest Twist Left-Right",
    "UpperChest Front-Back",
    "UpperChest Left-Right",
    "UpperChest Twist Left-Right",
    "Neck Nod Down-Up",
    "Neck Tilt Left-Right",
    "Neck Turn Left-Right",
    "Head Nod Down-Up",
    "Head Tilt Left-Right",
    "Head Turn Left-Right",
    "Left Eye Down-Up",
    "Left Eye In-Out",
    "Right Eye Down-Up",
    "Right Eye In-Out",
    "Jaw Close",
    "Jaw Left-Right",
    "Left Upper Leg Front-Back",
    "Left Upper Leg In-Out",
    "Left Upper Leg Twist In-Out",
    "Left Lower Leg Stretch",
    "Left Lower Leg Twist In-Out",
    "Left Foot Up-Down",
    "Left Foot Twist In-Out",
    "Left Toes Up-Down",
    "Right Upper Leg Front-Back",
    "Right Upper Leg In-Out",
    "Right Upper Leg Twist In-Out",
    "Right Lower Leg Stretch",
    "Right Lower Leg Twist In-Out",
    "Right Foot Up-Down",
    "Right Foot Twist In-Out",
    "Right Toes Up-Down",
    "Left Shoulder Down-Up",
    "Left Shoulder Front-Back",
    "Left Arm Down-Up",
    "Left Arm Front-Back",
    "Left Arm Twist In-Out",
    "Left Forearm Stretch",
    "Left Forearm Twist In-Out",
    "Left Hand Down-Up",
    "Left Hand In-Out",
    "Right Shoulder Down-Up",
    "Right Shoulder Front-Back",
    "Right Arm Down-Up",
    "Right Arm Front-Back",
    "Right Arm Twist In-Out",
    "Right Forearm Stretch",
    "Right Forearm Twist In-Out",
    "Right Hand Down-Up",
    "Right Hand In-Out",
    "Left Thumb 1 Stretched",
    "Left Thumb Spread",
    "Left Thumb 2 Stretched",
    "Left Thumb 3 Stretched",
    "Left Index 1 Stretched",
    "Left Index Spread",
    "Left Index 2 Stretched",
    "Left Index 3 Stretched",
    "Left Middle 1 Stretched",
    "Left Middle Spread",
    "Left Middle 2 Stretched",
    "Left Middle 3 Stretched",
    "Left Ring 1 Stretched",
    "Left Ring Spread",
    "Left Ring 2 Stretched",
    "Left Ring 3 Stretched",
    "Left Little 1 Stretched",
    "Left Little Spread",
    "Left Little 2 Stretched",
    "Left Little 3 Stretched",
    "Right Thumb 1 Stretched",
    "Right Thumb Spread",
    "Right Thumb 2 Stretched",
    "Right Thumb 3 Stretched",
    "Right Index 1 Stretched",
    "Right Index Spread",
    "Right Index 2 Stretched",
    "Right Index 3 Stretched",
    "Right Middle 1 Stretched",
    "Right Middle Spread",
    "Right Middle 2 Stretched",
    "Right Middle 3 Stretched",
    "Right Ring 1 Stretched",
    "Right Ring Spread",
    "Right Ring 2 Stretched",
    "Right Ring 3 Stretched",
    "Right Little 1 Stretched",
    "Right Little Spread",
    "Right Little 2 Stretched",
    "Right Little 3 Stretched",
];

const FINGER_RANGES: [(f32, f32); 20] = [
    (-20.0, 20.0),
    (-25.0, 25.0),
    (-40.0, 35.0),
    (-40.0, 35.0),
    (-50.0, 50.0),
    (-20.0, 20.0),
    (-45.0, 45.0),
    (-45.0, 45.0),
    (-50.0, 50.0),
    (-7.5, 7.5),
    (-45.0, 45.0),
    (-45.0, 45.0),
    (-50.0, 50.0),
    (-7.5, 7.5),
    (-45.0, 45.0),
    (-45.0, 45.0),
    (-50.0, 50.0),
    (-20.0, 20.0),
    (-45.0, 45.0),
    (-45.0, 45.0),
];

const LEG_RANGES: [(f32, f32); 8] = [
    (-90.0, 50.0),
    (-60.0, 60.0),
    (-60.0, 60.0),
    (-80.0, 80.0),
    (-90.0, 90.0),
    (-50.0, 50.0),
    (-30.0, 30.0),
    (-50.0, 50.0),
];

const ARM_RANGES: [(f32, f32); 9] = [
    (-15.0, 30.0),
    (-15.0, 15.0),
    (-60.0, 100.0),
    (-100.0, 100.0),
    (-90.0, 90.0),
    (-80.0, 80.0),
    (-90.0, 90.0),
    (-80.0, 80.0),
    (-40.0, 40.0),
];

/// Unity's default (min, max) in degrees per muscle.
pub const MUSCLE_RANGES: [(f32, f32); MUSCLES] = build_ranges();

const fn build_ranges() -> [(f32, f32); MUSCLES] {
    let mut r = [(-40.0f32, 40.0f32); MUSCLES];
    // 0..=14 spine, chest, neck, head: ±40 except the upper chest's ±20.
    r[6] = (-20.0, 20.0);
    r[7] = (-20.0, 20.0);
    r[8] = (-20.0, 20.0);
    r[15] = (-10.0, 15.0);
    r[16] = (-20.0, 20.0);
    r[17] = (-10.0, 15.0);
    r[18] = (-20.0, 20.0);
    r[19] = (-10.0, 10.0);
    r[20] = (-10.0, 10.0);
    let mut i = 0;
    while i < 8 {
        r[21 + i] = LEG_RANGES[i];
        r[29 + i] = LEG_RANGES[i];
        i += 1;
    }
    let mut i = 0;
    while i < 9 {
        r[37 + i] = ARM_RANGES[i];
        r[46 + i] = ARM_RANGES[i];
        i += 1;
    }
    let mut i = 0;
    while i < 20 {
        r[55 + i] = FINGER_RANGES[i];
        r[75 + i] = FINGER_RANGES[i];
        i += 1;
    }
    r
}

/// Muscle indices by name, for code that writes poses by hand.
pub mod idx {
    pub const SPINE_FRONT_BACK: usize = 0;
    pub const SPINE_LEFT_RIGHT: usize = 1;
    pub const SPINE_TWIST: usize = 2;
    pub const CHEST_FRONT_BACK: usize = 3;
    pub const CHEST_LEFT_RIGHT: usize = 4;
    pub const CHEST_TWIST: usize = 5;
    pub const UPPER_CHEST_FRONT_BACK: usize = 6;
    pub const UPPER_CHEST_LEFT_RIGHT: usize = 7;
    pub const UPPER_CHEST_TWIST: usize = 8;
    pub const NECK_NOD: usize = 9;
    pub const NECK_TILT: usize = 10;
    pub const NECK_TURN: usize = 11;
    pub const HEAD_NOD: usize = 12;
    pub const HEAD_TILT: usize = 13;
    pub const HEAD_TURN: usize = 14;
    pub const RIGHT_EYE_DOWN_UP: usize = 17;
    pub const RIGHT_EYE_IN_OUT: usize = 18;
    pub const JAW_CLOSE: usize = 19;
    pub const JAW_LEFT_RIGHT: usize = 20;
    /// First muscle of the left leg block (Upper Leg Front-Back); the right leg is `+ 8`.
    pub const LEFT_LEG: usize = 21;
    pub const RIGHT_LEG: usize = 29;
    /// First muscle of the left arm block (Shoulder Down-Up); the right arm is `+ 9`.
    pub const LEFT_ARM: usize = 37;
    pub const RIGHT_ARM: usize = 46;
    /// Offsets inside an arm block.
    pub const SHOULDER_DOWN_UP: usize = 0;
    pub const SHOULDER_FRONT_BACK: usize = 1;
    pub const ARM_DOWN_UP: usize = 2;
    pub const ARM_FRONT_BACK: usize = 3;
    pub const ARM_TWIST: usize = 4;
    pub const FOREARM_STRETCH: usize = 5;
    pub const FOREARM_TWIST: usize = 6;
    pub const HAND_DOWN_UP: usize = 7;
    pub const HAND_IN_OUT: usize = 8;
    /// Offsets inside a leg block.
    pub const UPPER_LEG_FRONT_BACK: usize = 0;
    pub const UPPER_LEG_IN_OUT: usize = 1;
    pub const UPPER_LEG_TWIST: usize = 2;
    pub const LOWER_LEG_STRETCH: usize = 3;
    pub const LOWER_LEG_TWIST: usize = 4;
    pub const FOOT_UP_DOWN: usize = 5;
    pub const FOOT_TWIST: usize = 6;
    pub const TOES_UP_DOWN: usize = 7;
    /// First muscle of the left / right finger block (Thumb 1 Stretched); each finger has 4:
    /// 1 Stretched, Spread, 2 Stretched, 3 Stretched, in the order thumb, index, middle, ring, little.
    pub const LEFT_FINGERS: usize = 55;
    pub const RIGHT_FINGERS: usize = 75;
}

/// The angle in degrees that muscle `i` at value `m` turns its bone away from muscle zero.
#[inline]
pub fn muscle_degrees(i: usize, m: f32) -> f32 {
    let (lo, hi) = MUSCLE_RANGES[i];
    if m >= 0.0 { m * hi } else { m * -lo }
}

/// Inverse of [`muscle_degrees`]: the muscle value (unclamped) for an angle in degrees.
#[inline]
pub fn muscle_value(i: usize, degrees: f32) -> f32 {
    let (lo, hi) = MUSCLE_RANGES[i];
    if degrees >= 0.0 { degrees / hi } else { degrees / -lo }
}

/// Index of a muscle by its Unity name (exact match).
pub fn muscle_index(name: &str) -> Option<usize> {
    MUSCLE_NAMES.iter().position(|n| *n == name)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn table_matches_reference_spot_checks() {
        assert_eq!(MUSCLE_NAMES[48], "Right Arm Down-Up");
        assert_eq!(MUSCLE_RANGES[48], (-60.0, 100.0));
        assert_eq!(MUSCLE_RANGES[21], (-90.0, 50.0));
        assert_eq!(MUSCLE_RANGES[64], (-7.5, 7.5));
        assert_eq!(MUSCLE_RANGES[77], (-40.0, 35.0));
        assert_eq!(MUSCLE_RANGES[15], (-10.0, 15.0));
        assert_eq!(MUSCLE_RANGES[7], (-20.0, 20.0));
        assert_eq!(MUSCLE_RANGES[94], (-45.0, 45.0));
        assert_eq!(muscle_index("Left Little 3 Stretched"), Some(74));
        // Left and right blocks mirror each other name for name.
        for i in 21..29 {
            assert_eq!(MUSCLE_NAMES[i].replace("Left", "Right"), MUSCLE_NAMES[i + 8]);
        }
        for i in 37..46 {
            assert_eq!(MUSCLE_NAMES[i].replace("Left", "Right"), MUSCLE_NAMES[i + 9]);
        }
        for i in 55..75 {
            assert_eq!(MUSCLE_NAMES[i].replace("Left", "Right"), MUSCLE_NAMES[i + 20]);
        }
    }

    #[test]
    fn value_degree_round_trip() {
        for i in 0..MUSCLES {
            for m in [-1.0f32, -0.3, 0.0, 0.45, 1.0] {
                assert!((muscle_value(i, muscle_degrees(i, m)) - m).abs() < 1e-6);
            }
        }
    }
}
