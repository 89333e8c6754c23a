//! What the commands write for people to read: tables in the layouts of chapter 4 (`tables`),
//! which way a policy turns first (`first_turn`), success by how near the target is to the start
//! (`nearness`), each test episode's outcome kept beside a study record (`outcomes`), two
//! methods paired over programs and seeds and where each wins (`wins`), charts (`plot`), top-down maps of a room (`map`) and an episode's trajectory
//! drawn on one (`trajectory`), the one font they share (`fonts`), and a long command's progress
//! on the terminal (`progress`). The study's own tables and charts are beside the study
//! (`commands::study`).

pub mod first_turn;
pub mod fonts;
pub mod map;
pub mod nearness;
pub mod outcomes;
pub mod plot;
pub mod progress;
pub mod tables;
pub mod trajectory;
pub mod wins;
