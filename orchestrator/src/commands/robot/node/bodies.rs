//! REP-155's bodies (`--gesture skeleton`): a tracker publishes the bodies it follows in each
//! image on `/humans/bodies/tracked`, and each body's keypoints on
//! `/humans/bodies/<id>/skeleton2d`, both stamped as the image. The node follows the ids as they
//! come and go, and hands the person each image's body once all of it has come.

use std::collections::VecDeque;

use ros2_client::dds::{Node, Subscription};

use crate::commands::robot::dds::{self, drain, seconds};
use crate::commands::robot::msgs::{IdsList, Skeleton2D};
use crate::commands::robot::names::Resolved;

/// Images' worth of the tracker's messages kept while their parts come.
const KEEP: usize = 32;

/// The capture's keypoints (COCO): shoulders, elbows, wrists, hips. The surest body of several
/// is the one most sure of these.
const ARMS_AND_HIPS: [usize; 8] = [2, 3, 4, 5, 6, 7, 8, 11];

pub struct Bodies {
    tracked: Subscription<IdsList>,
    /// The followed bodies' keypoint topics, by id.
    skeletons: Vec<(String, Subscription<Skeleton2D>)>,
    /// What the tracker said of each image not yet handed on, oldest first, and the skeletons
    /// heard (by id).
    lists: VecDeque<IdsList>,
    heard: VecDeque<(String, Skeleton2D)>,
}

impl Bodies {
    pub fn open(node: &mut Node, names: &Resolved) -> anyhow::Result<Bodies> {
        Ok(Bodies {
            tracked: dds::subscription(node, &names.tracked, dds::sensor())?,
            skeletons: Vec::new(),
            lists: VecDeque::new(),
            heard: VecDeque::new(),
        })
    }

    /// Reads the tracker: a new body's keypoints are subscribed to, a body no longer tracked
    /// is let go. A message of the wrong type: the line that says so.
    pub fn listen(&mut self, node: &mut Node, names: &Resolved) -> anyhow::Result<Option<String>> {
        let (lists, mut garbled) = drain(&self.tracked);
        garbled = garbled.map(|e| dds::not_of_its_type(&names.tracked, &e));
        if let Some(now) = lists.last() {
            self.skeletons.retain(|(id, _)| now.ids.contains(id));
            for id in &now.ids {
                if !self.skeletons.iter().any(|(known, _)| known == id) {
                    let sub = dds::subscription(node, &names.skeleton(id), dds::sensor())?;
                    self.skeletons.push((id.clone(), sub));
                }
            }
        }
        self.lists.extend(lists);
        for (id, sub) in &self.skeletons {
            let (heard, e) = drain(sub);
            garbled = garbled.or(e.map(|e| dds::not_of_its_type(&names.skeleton(id), &e)));
            self.heard.extend(heard.into_iter().map(|s| (id.clone(), s)));
        }
        while self.lists.len() > KEEP {
            self.lists.pop_front();
        }
        while self.heard.len() > KEEP * 4 {
            self.heard.pop_front();
        }
        Ok(garbled)
    }

    /// The images the tracker is done with, oldest first: each one's stamp and the surest body
    /// found in it (`None`: it tracked nobody). An image is done when every body it tracked has
    /// come, or a later image's list has (a body lost on the way does not hold it up).
    pub fn ready(&mut self) -> Vec<(f64, Option<Skeleton2D>)> {
        let mut out = Vec::new();
        while let Some(list) = self.lists.front() {
            let stamp = list.header.stamp;
            let bodies: Vec<&Skeleton2D> = self
                .heard
                .iter()
                .filter(|(id, s)| s.header.stamp == stamp && list.ids.contains(id))
                .map(|(_, s)| s)
                .collect();
            if bodies.len() < list.ids.len() && self.lists.len() == 1 {
                break;
            }
            let surest = bodies.into_iter().max_by(|a, b| sureness(a).total_cmp(&sureness(b))).cloned();
            let lost = surest.is_none() && !list.ids.is_empty();
            if !lost {
                out.push((seconds(stamp), surest));
            }
            self.heard.retain(|(_, s)| seconds(s.header.stamp) > seconds(stamp));
            self.lists.pop_front();
        }
        out
    }
}

fn sureness(s: &Skeleton2D) -> f32 {
    ARMS_AND_HIPS.iter().map(|&k| s.skeleton[k].c).sum()
}
