//! The six NOCS object categories.

use serde::{Deserialize, Serialize};
use std::fmt;
use std::str::FromStr;

/// A NOCS object category. Ids are 1-based as in the NOCS dataset
/// (1 bottle, 2 bowl, 3 camera, 4 can, 5 laptop, 6 mug).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Category {
    /// Bottles (symmetric about y).
    Bottle,
    /// Bowls (symmetric about y).
    Bowl,
    /// Cameras.
    Camera,
    /// Cans (symmetric about y).
    Can,
    /// Laptops.
    Laptop,
    /// Mugs (symmetric about y when the handle is not visible).
    Mug,
}

impl Category {
    /// All categories in id order.
    pub const ALL: [Category; 6] =
        [Category::Bottle, Category::Bowl, Category::Camera, Category::Can, Category::Laptop, Category::Mug];

    /// The 1-based NOCS class id.
    pub fn id(self) -> u8 {
        self as u8 + 1
    }

    /// The category with a 1-based NOCS class id.
    pub fn from_id(id: u8) -> Option<Category> {
        Category::ALL.get(usize::from(id).checked_sub(1)?).copied()
    }

    /// The lowercase NOCS name ("bottle", ...).
    pub fn name(self) -> &'static str {
        match self {
            Category::Bottle => "bottle",
            Category::Bowl => "bowl",
            Category::Camera => "camera",
            Category::Can => "can",
            Category::Laptop => "laptop",
            Category::Mug => "mug",
        }
    }

    /// Whether the evaluation treats this object as symmetric about its y axis:
    /// bottles, bowls and cans always, mugs when the handle is not visible.
    pub fn is_symmetric(self, handle_visible: bool) -> bool {
        match self {
            Category::Bottle | Category::Bowl | Category::Can => true,
            Category::Mug => !handle_visible,
            Category::Camera | Category::Laptop => false,
        }
    }
}

impl fmt::Display for Category {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.pad(self.name())
    }
}

impl FromStr for Category {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Category::ALL
            .into_iter()
            .find(|c| c.name() == s)
            .ok_or_else(|| format!("unknown category {s:?} (expected one of bottle, bowl, camera, can, laptop, mug)"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ids_round_trip_and_are_one_based() {
        for c in Category::ALL {
            assert_eq!(Category::from_id(c.id()), Some(c));
            assert_eq!(c.name().parse::<Category>(), Ok(c));
        }
        assert_eq!(Category::Bottle.id(), 1);
        assert_eq!(Category::Mug.id(), 6);
        assert_eq!(Category::from_id(0), None);
        assert_eq!(Category::from_id(7), None);
        assert!("chair".parse::<Category>().is_err());
    }
}
