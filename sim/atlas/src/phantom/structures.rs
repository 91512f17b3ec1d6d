//! The phantom's ground-truth structures, what the atlas ships of them, and their HU values.

use stylet_physics::{HeuristicClass, LabelId};

/// Every structure the generator knows. Stored per voxel (u8) in the ground-truth volume.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
#[repr(u8)]
pub enum Structure {
    Air = 0,
    Skin,
    Fat,
    Muscle,
    Fascia,
    Rib,
    Cartilage,
    Vertebra,
    Disc,
    SpinalCord,
    LungRight,
    LungLeft,
    Diaphragm,
    Heart,
    Liver,
    PortalVein,
    HepaticVein,
    VenaCava,
    Aorta,
    BileDuct,
    TargetDuct,
    Lesion,
    Gallbladder,
    Kidney,
    Spleen,
    Stomach,
    Gas,
    Colon,
    Bowel,
    Pancreas,
    Duodenum,
}

impl Structure {
    pub const ALL: [Structure; 31] = [
        Structure::Air,
        Structure::Skin,
        Structure::Fat,
        Structure::Muscle,
        Structure::Fascia,
        Structure::Rib,
        Structure::Cartilage,
        Structure::Vertebra,
        Structure::Disc,
        Structure::SpinalCord,
        Structure::LungRight,
        Structure::LungLeft,
        Structure::Diaphragm,
        Structure::Heart,
        Structure::Liver,
        Structure::PortalVein,
        Structure::HepaticVein,
        Structure::VenaCava,
        Structure::Aorta,
        Structure::BileDuct,
        Structure::TargetDuct,
        Structure::Lesion,
        Structure::Gallbladder,
        Structure::Kidney,
        Structure::Spleen,
        Structure::Stomach,
        Structure::Gas,
        Structure::Colon,
        Structure::Bowel,
        Structure::Pancreas,
        Structure::Duodenum,
    ];

    pub fn from_u8(v: u8) -> Option<Structure> {
        Structure::ALL.get(v as usize).copied()
    }

    pub fn name(self) -> &'static str {
        match self {
            Structure::Air => "air",
            Structure::Skin => "skin",
            Structure::Fat => "fat",
            Structure::Muscle => "muscle",
            Structure::Fascia => "intercostal fascia",
            Structure::Rib => "rib",
            Structure::Cartilage => "costal cartilage",
            Structure::Vertebra => "vertebra",
            Structure::Disc => "intervertebral disc",
            Structure::SpinalCord => "spinal cord",
            Structure::LungRight => "right lung",
            Structure::LungLeft => "left lung",
            Structure::Diaphragm => "diaphragm",
            Structure::Heart => "heart",
            Structure::Liver => "liver",
            Structure::PortalVein => "portal vein",
            Structure::HepaticVein => "hepatic vein",
            Structure::VenaCava => "inferior vena cava",
            Structure::Aorta => "aorta",
            Structure::BileDuct => "bile duct",
            Structure::TargetDuct => "right hepatic duct",
            Structure::Lesion => "lesion obstructing the common bile duct",
            Structure::Gallbladder => "gallbladder",
            Structure::Kidney => "kidney",
            Structure::Spleen => "spleen",
            Structure::Stomach => "stomach",
            Structure::Gas => "bowel / stomach gas",
            Structure::Colon => "colon",
            Structure::Bowel => "small bowel",
            Structure::Pancreas => "pancreas",
            Structure::Duodenum => "duodenum",
        }
    }

    /// The partial label the atlas ships for this structure (Table A.2), or 0 when the structure
    /// is left to the heuristic or not labelled at all. Ids follow `atlases/ptcd.toml`.
    pub fn partial_label(self) -> LabelId {
        match self {
            Structure::Liver => 10,
            Structure::PortalVein => 11,
            Structure::HepaticVein => 12,
            Structure::VenaCava => 13,
            Structure::Aorta => 14,
            Structure::BileDuct => 20,
            Structure::TargetDuct => 21,
            Structure::Fascia => 30,
            Structure::LungRight => 40,
            Structure::LungLeft => 41,
            _ => 0,
        }
    }

    /// The heuristic class a careful reader of the CT would assign to this structure at depth 0,
    /// for structures without a partial label: the ground truth the heuristic is tested against.
    pub fn truth_class(self) -> Option<HeuristicClass> {
        if self.partial_label() != 0 {
            return None;
        }
        Some(match self {
            Structure::Air | Structure::Gas => HeuristicClass::Air,
            Structure::Skin => HeuristicClass::Skin,
            Structure::Rib | Structure::Vertebra => HeuristicClass::Bone,
            _ => HeuristicClass::Fat,
        })
    }
}

/// CT values (HU) of the phantom: a portal-venous-phase contrast CT, values from standard
/// radiology references (liver ≈ 100, portal vein ≈ 150, dilated ducts ≈ water).
pub mod hu {
    pub const AIR: f64 = -1000.0;
    pub const SKIN: f64 = 35.0;
    pub const FAT: f64 = -100.0;
    pub const VISCERAL_FAT: f64 = -90.0;
    pub const MUSCLE: f64 = 55.0;
    pub const FASCIA: f64 = 55.0;
    pub const RIB_CORTEX: f64 = 750.0;
    pub const MARROW: f64 = 260.0;
    pub const CARTILAGE: f64 = 130.0;
    pub const VERTEBRA_CORTEX: f64 = 700.0;
    pub const CANCELLOUS: f64 = 240.0;
    pub const DISC: f64 = 85.0;
    pub const CORD: f64 = 35.0;
    pub const CSF: f64 = 8.0;
    pub const LUNG: f64 = -840.0;
    pub const DIAPHRAGM: f64 = 50.0;
    pub const HEART: f64 = 120.0;
    pub const LIVER: f64 = 100.0;
    pub const PORTAL_VEIN: f64 = 150.0;
    pub const HEPATIC_VEIN: f64 = 140.0;
    pub const VENA_CAVA: f64 = 130.0;
    pub const AORTA: f64 = 160.0;
    pub const BILE: f64 = 8.0;
    pub const LESION: f64 = 45.0;
    pub const GALLBLADDER_WALL: f64 = 45.0;
    pub const KIDNEY: f64 = 150.0;
    pub const RENAL_SINUS: f64 = -60.0;
    pub const SPLEEN: f64 = 115.0;
    pub const STOMACH_WALL: f64 = 60.0;
    pub const STOMACH_CONTENT: f64 = 15.0;
    pub const COLON_WALL: f64 = 45.0;
    pub const STOOL: f64 = -40.0;
    pub const BOWEL: f64 = 30.0;
    pub const PANCREAS: f64 = 95.0;
    pub const DUODENUM: f64 = 20.0;
}
