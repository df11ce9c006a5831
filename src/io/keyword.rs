//! The words that name a choice on the command line and in files (`--depth-holes fill`,
//! `--only panel`): one list per type, so that the parser, the help text and the messages
//! that quote an option's value cannot disagree.

/// A type whose values are chosen by name.
pub trait Keyword: Copy + PartialEq + 'static {
    /// Every value with its name, in the order help texts list them.
    const ALL: &'static [(Self, &'static str)];

    /// The value's name.
    fn keyword(self) -> &'static str {
        Self::ALL
            .iter()
            .find(|(value, _)| *value == self)
            .map(|(_, name)| *name)
            .expect("every value is listed in Keyword::ALL")
    }

    /// The value of that name.
    fn from_keyword(name: &str) -> Option<Self> {
        Self::ALL
            .iter()
            .find(|(_, n)| *n == name)
            .map(|(value, _)| *value)
    }
}

/// The weave's filter between view centres (the `interleave` crate knows no command line).
impl Keyword for interleave::Blend {
    const ALL: &'static [(Self, &'static str)] = &[
        (interleave::Blend::Nearest, "nearest"),
        (interleave::Blend::Linear, "linear"),
        (interleave::Blend::Gaussian, "gaussian"),
    ];
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Clone, Copy, Debug, PartialEq)]
    enum Side {
        Left,
        Right,
    }

    impl Keyword for Side {
        const ALL: &'static [(Self, &'static str)] =
            &[(Side::Left, "left"), (Side::Right, "right")];
    }

    #[test]
    fn names_round_trip() {
        for &(value, name) in Side::ALL {
            assert_eq!(value.keyword(), name);
            assert_eq!(Side::from_keyword(name), Some(value));
        }
        assert_eq!(Side::from_keyword("middle"), None);
    }
}
